//! Surfel trees: a species sampled into Guennebaud and Paulin's LDC tree, as the file
//! stores it and the `surfel` method draws it (the record of kind 5, its packed surfels,
//! its checks and its bytes).

use glam::Vec3;

use super::*;
use crate::model::mesh::Aabb;
use crate::sphere::OctaLayout;

/// Words (u32) one packed surfel takes.
pub const SURFEL_WORDS: usize = 3;
/// Most levels of a surfel tree.
pub const MAX_SURFEL_LEVELS: u32 = 16;
/// Most children of a node (an octree).
pub const MAX_SURFEL_CHILDREN: usize = 8;
/// Allowed voxels along each axis of a surfel tree's density volume.
pub const SURFEL_DENSITY_DIM_RANGE: RangeInclusive<u32> = 1..=64;
/// Allowed level-0 surfel budgets a species is sampled with; 0 means no surfels.
pub const SURFEL_BUDGET_RANGE: RangeInclusive<u32> = 1_000..=4_000_000;
/// Steps of a position within its tree's box (14 bits an axis).
const POSITION_STEPS: f32 = 16383.0;
/// Steps of a surfel's sky openness (6 bits).
const OPENNESS_STEPS: f32 = 63.0;
/// Steps of a surfel's coverage (7 bits).
const COVERAGE_STEPS: f32 = 127.0;
/// The word a node's unused child slots hold.
const NO_CHILD: u32 = u32::MAX;

/// One sample of a tree's surface, in the tree frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Surfel {
    pub position: Vec3,
    /// Unit normal (a leaf's, which is two-sided, turned upwards).
    pub normal: Vec3,
    /// Linear albedo.
    pub albedo: Vec3,
    /// Lit as foliage (two-sided, the tree's tint); bark otherwise.
    pub foliage: bool,
    /// The share of its cell (its level's spacing squared, across its LDI's axis) the
    /// surfaces it stands for cover: a surfel is drawn with this probability, so that a
    /// sparse crown seen from afar lets as much through as its triangles do.
    pub coverage: f32,
    /// The share of the sky its own tree leaves open to it (cosine-weighted over the upper
    /// hemisphere): 1 outside the crown, less inside.
    pub openness: f32,
}

/// `s` packed in [`SURFEL_WORDS`] words, its position quantised in the box
/// `qmin + [0, 1]³ qsize` (the layout is in the format's docs: `SURFEL TREE RECORD`).
pub fn pack_surfel(s: &Surfel, qmin: Vec3, qsize: Vec3) -> [u32; SURFEL_WORDS] {
    let q = ((s.position - qmin) / qsize.max(Vec3::splat(1e-9))).clamp(Vec3::ZERO, Vec3::ONE)
        * POSITION_STEPS;
    let q = q.round().as_uvec3();
    let e = OctaLayout::Full
        .dir_to_uv(s.normal)
        .to_array()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u32);
    let c = s
        .albedo
        .clamp(Vec3::ZERO, Vec3::ONE)
        .to_array()
        .map(|v| (v.sqrt() * 255.0).round() as u32);
    let cover = (s.coverage.clamp(0.0, 1.0) * COVERAGE_STEPS)
        .round()
        .max(1.0) as u32;
    let open = (s.openness.clamp(0.0, 1.0) * OPENNESS_STEPS).round() as u32;
    [
        q.x | (q.y << 14) | ((q.z & 0xf) << 28),
        (q.z >> 4) | (e[0] << 10) | (e[1] << 18) | (open << 26),
        c[0] | (c[1] << 8) | (c[2] << 16) | (u32::from(s.foliage) << 24) | (cover << 25),
    ]
}

/// The inverse of [`pack_surfel`].
pub fn unpack_surfel(w: [u32; SURFEL_WORDS], qmin: Vec3, qsize: Vec3) -> Surfel {
    let q = Vec3::new(
        (w[0] & 0x3fff) as f32,
        ((w[0] >> 14) & 0x3fff) as f32,
        ((w[0] >> 28) | ((w[1] & 0x3ff) << 4)) as f32,
    ) / POSITION_STEPS;
    let uv = glam::Vec2::new(((w[1] >> 10) & 0xff) as f32, ((w[1] >> 18) & 0xff) as f32) / 255.0;
    let c = [w[2] & 0xff, (w[2] >> 8) & 0xff, (w[2] >> 16) & 0xff].map(|v| {
        let x = v as f32 / 255.0;
        x * x
    });
    Surfel {
        position: qmin + q * qsize,
        normal: OctaLayout::Full.uv_to_dir(uv),
        albedo: Vec3::from(c),
        foliage: (w[2] >> 24) & 1 != 0,
        coverage: (w[2] >> 25) as f32 / COVERAGE_STEPS,
        openness: (w[1] >> 26) as f32 / OPENNESS_STEPS,
    }
}

/// A block of one level of a surfel tree: its surfels (a range of the tree's), its bounds
/// in the tree frame and its children one level finer.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfelNode {
    pub level: u32,
    pub bounds: Aabb,
    pub first: u32,
    pub count: u32,
    /// Indices of the child nodes (none at level 0), at most [`MAX_SURFEL_CHILDREN`].
    pub children: Vec<u32>,
}

/// A tree's surfaces as a volume of extinction coefficients (1/m) over its bounds, for its
/// self-shadowing: voxel (i, j, k) at `(k*y + j)*x + i`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SurfelDensity {
    pub origin: Vec3,
    pub voxel: f32,
    pub dims: [u32; 3],
    pub sigma: Vec<f32>,
}

/// One species' LDC tree: its levels, its octree of blocks, its packed surfels and its
/// density volume.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfelSet {
    pub species: u32,
    /// The box the surfels' positions are quantised in (the tree's bounds).
    pub bounds: Aabb,
    /// Spacing of level 0 (m); level l has `spacing0 · 2^l`.
    pub spacing0: f32,
    /// Per level, the gain its coverages were raised by (1 - (1 - c)^gain) so that its
    /// silhouettes match level 0's.
    pub gains: Vec<f32>,
    /// Surfels per level, finest first.
    pub per_level: Vec<u32>,
    /// Every node; the coarsest level's are the roots.
    pub nodes: Vec<SurfelNode>,
    /// The nodes of the coarsest level, ascending (not stored: found from `nodes`).
    pub roots: Vec<u32>,
    /// Every surfel packed ([`pack_surfel`] in `bounds`), grouped by node.
    pub words: Vec<u32>,
    pub density: SurfelDensity,
}

/// Bytes of a surfel tree record besides its data.
pub(super) const SURFEL_RECORD_FIXED_BYTES: u64 = 80;
/// Bytes a level takes in a record (gain, surfel count).
const LEVEL_BYTES: u64 = 8;
/// Bytes a node takes in a record.
const NODE_BYTES: u64 = 16 + 24 + 4 * MAX_SURFEL_CHILDREN as u64;

impl SurfelSet {
    /// Packed surfels.
    pub fn surfel_count(&self) -> u64 {
        (self.words.len() / SURFEL_WORDS) as u64
    }

    /// Levels, finest first.
    pub fn levels(&self) -> usize {
        self.per_level.len()
    }

    /// Spacing of level `l` (m, tree frame).
    pub fn spacing(&self, level: u32) -> f32 {
        self.spacing0 * (1u32 << level.min(31)) as f32
    }

    /// The nodes of the coarsest level of `nodes`, ascending.
    pub fn roots_of(nodes: &[SurfelNode], levels: usize) -> Vec<u32> {
        (0..nodes.len() as u32)
            .filter(|&n| nodes[n as usize].level + 1 == levels as u32)
            .collect()
    }

    /// Bytes of the record's data after its fixed part, for these counts.
    pub fn data_bytes(levels: u32, nodes: u32, surfels: u64, density_dims: [u32; 3]) -> u64 {
        let voxels: u64 = density_dims.iter().map(|&d| u64::from(d)).product();
        LEVEL_BYTES * u64::from(levels)
            + NODE_BYTES * u64::from(nodes)
            + 4 * SURFEL_WORDS as u64 * surfels
            + 4 * voxels
    }

    /// Bytes of the whole record.
    pub fn record_bytes(&self) -> u64 {
        SURFEL_RECORD_FIXED_BYTES
            + Self::data_bytes(
                self.per_level.len() as u32,
                self.nodes.len() as u32,
                self.surfel_count(),
                self.density.dims,
            )
    }

    /// What is wrong with the fixed part of a record (counts, box, spacing, density
    /// volume), if anything.
    fn fixed_problem(&self, levels: u32, nodes: u32, surfels: u64) -> Option<String> {
        if !(1..=MAX_SURFEL_LEVELS).contains(&levels) {
            return Some(format!("{levels} levels, not 1 to {MAX_SURFEL_LEVELS}"));
        }
        if nodes == 0 || surfels == 0 {
            return Some(format!(
                "{nodes} nodes and {surfels} surfels: none may be 0"
            ));
        }
        let corners = [self.bounds.min, self.bounds.max, self.density.origin];
        if !corners.iter().all(|c| c.is_finite()) || !self.bounds.max.cmpge(self.bounds.min).all() {
            return Some(
                "its box or density origin is not finite, or its box is inside out".into(),
            );
        }
        for (what, v) in [
            ("spacing", self.spacing0),
            ("density voxel", self.density.voxel),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Some(format!("its {what} {v} is not a finite number above 0"));
            }
        }
        if let Some(d) = self
            .density
            .dims
            .iter()
            .find(|d| !SURFEL_DENSITY_DIM_RANGE.contains(d))
        {
            return Some(format!(
                "a density volume of {d} voxels an axis, not 1 to 64"
            ));
        }
        None
    }

    /// What is wrong with this tree, if anything: its counts and sizes, its levels' gains
    /// and counts, every node's level, surfel range and children (one level finer each, so
    /// the octree ends), its density's values.
    pub fn problem(&self) -> Option<String> {
        let levels = self.per_level.len();
        if let Some(p) =
            self.fixed_problem(levels as u32, self.nodes.len() as u32, self.surfel_count())
        {
            return Some(p);
        }
        if !self.words.len().is_multiple_of(SURFEL_WORDS) || self.gains.len() != levels {
            return Some("its surfel words or its gains do not match its counts".into());
        }
        let voxels: u64 = self.density.dims.iter().map(|&d| u64::from(d)).product();
        if self.density.sigma.len() as u64 != voxels {
            return Some(format!(
                "its density volume holds {} values, expected {voxels}",
                self.density.sigma.len()
            ));
        }
        if let Some(g) = self.gains.iter().find(|g| !(1.0..=16.0).contains(*g)) {
            return Some(format!("a level's gain is {g}, not 1 to 16"));
        }
        let total: u64 = self.per_level.iter().map(|&c| u64::from(c)).sum();
        if total != self.surfel_count() {
            return Some(format!(
                "its levels count {total} surfels but it holds {}",
                self.surfel_count()
            ));
        }
        if let Some(v) = self
            .density
            .sigma
            .iter()
            .find(|v| !(v.is_finite() && **v >= 0.0))
        {
            return Some(format!(
                "a density value is {v}, not a finite number from 0"
            ));
        }
        for (i, n) in self.nodes.iter().enumerate() {
            let end = u64::from(n.first) + u64::from(n.count);
            let bad = if n.level as usize >= levels {
                Some(format!("its level {} is past the tree's {levels}", n.level))
            } else if n.count == 0 || end > self.surfel_count() {
                Some(format!(
                    "its surfels {}..{end} are empty or past the tree's {}",
                    n.first,
                    self.surfel_count()
                ))
            } else if !(n.bounds.min.is_finite() && n.bounds.max.is_finite()) {
                Some("its bounds are not finite".into())
            } else if n.children.len() > MAX_SURFEL_CHILDREN
                || (n.level == 0 && !n.children.is_empty())
            {
                Some(format!("it has {} children", n.children.len()))
            } else {
                n.children.iter().find_map(|&c| {
                    let ok = self
                        .nodes
                        .get(c as usize)
                        .is_some_and(|child| child.level + 1 == n.level);
                    (!ok).then(|| format!("its child {c} is not a node one level finer"))
                })
            };
            if let Some(reason) = bad {
                return Some(format!("node {i}: {reason}"));
            }
        }
        if self.roots != Self::roots_of(&self.nodes, levels) {
            return Some("its roots are not the nodes of its coarsest level".into());
        }
        None
    }

    /// Appends the record's bytes to `w`.
    pub(super) fn write<W: std::io::Write + ?Sized>(&self, w: &mut W) -> std::io::Result<()> {
        let levels = self.per_level.len() as u32;
        let words = [
            self.species,
            levels,
            self.nodes.len() as u32,
            self.surfel_count() as u32,
        ];
        let mut fixed = Vec::with_capacity(SURFEL_RECORD_FIXED_BYTES as usize);
        for v in words {
            fixed.extend_from_slice(&v.to_le_bytes());
        }
        for v in [self.bounds.min, self.bounds.max] {
            for c in v.to_array() {
                fixed.extend_from_slice(&c.to_le_bytes());
            }
        }
        fixed.extend_from_slice(&self.spacing0.to_le_bytes());
        for c in self.density.origin.to_array() {
            fixed.extend_from_slice(&c.to_le_bytes());
        }
        fixed.extend_from_slice(&self.density.voxel.to_le_bytes());
        for d in self.density.dims {
            fixed.extend_from_slice(&d.to_le_bytes());
        }
        let data = Self::data_bytes(levels, words[2], self.surfel_count(), self.density.dims);
        fixed.extend_from_slice(&data.to_le_bytes());
        w.write_all(&fixed)?;
        let mut out = Vec::with_capacity(data as usize);
        for (g, c) in self.gains.iter().zip(&self.per_level) {
            out.extend_from_slice(&g.to_le_bytes());
            out.extend_from_slice(&c.to_le_bytes());
        }
        for n in &self.nodes {
            for v in [n.level, n.first, n.count, n.children.len() as u32] {
                out.extend_from_slice(&v.to_le_bytes());
            }
            for c in n
                .bounds
                .min
                .to_array()
                .into_iter()
                .chain(n.bounds.max.to_array())
            {
                out.extend_from_slice(&c.to_le_bytes());
            }
            for k in 0..MAX_SURFEL_CHILDREN {
                let c = n.children.get(k).copied().unwrap_or(NO_CHILD);
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        for v in &self.words {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for v in &self.density.sigma {
            out.extend_from_slice(&v.to_le_bytes());
        }
        w.write_all(&out)
    }

    /// The record whose fixed part is `fixed` ([`SURFEL_RECORD_FIXED_BYTES`] bytes), its
    /// data still to come: the set (data empty) and the data's length, or what is wrong.
    pub(super) fn from_fixed(fixed: &[u8]) -> Result<(SurfelSet, u64), String> {
        let u = |k: usize| u32::from_le_bytes(fixed[4 * k..4 * k + 4].try_into().unwrap_or([0; 4]));
        let f = |k: usize| f32::from_bits(u(k));
        let v = |k: usize| Vec3::new(f(k), f(k + 1), f(k + 2));
        let (levels, nodes, surfels) = (u(1), u(2), u(3));
        let set = SurfelSet {
            species: u(0),
            bounds: Aabb::new(v(4), v(7)),
            spacing0: f(10),
            gains: Vec::new(),
            per_level: Vec::new(),
            nodes: Vec::new(),
            roots: Vec::new(),
            words: Vec::new(),
            density: SurfelDensity {
                origin: v(11),
                voxel: f(14),
                dims: [u(15), u(16), u(17)],
                sigma: Vec::new(),
            },
        };
        let data = u64::from_le_bytes(fixed[72..80].try_into().unwrap_or([0; 8]));
        if let Some(p) = set.fixed_problem(levels, nodes, surfels.into()) {
            return Err(p);
        }
        let expected = Self::data_bytes(levels, nodes, surfels.into(), set.density.dims);
        if data != expected {
            return Err(format!("its data holds {data} bytes, expected {expected}"));
        }
        Ok((set, data))
    }

    /// Fills `self` (from [`Self::from_fixed`]) with its `data`, and checks the whole.
    pub(super) fn fill(&mut self, fixed: &[u8], data: &[u8]) -> Result<(), String> {
        let count =
            |k: usize| u32::from_le_bytes(fixed[4 * k..4 * k + 4].try_into().unwrap_or([0; 4]));
        let (levels, nodes, surfels) = (count(1) as usize, count(2) as usize, count(3) as usize);
        let mut words = data
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]));
        let mut next = || words.next().unwrap_or(0);
        for _ in 0..levels {
            self.gains.push(f32::from_bits(next()));
            self.per_level.push(next());
        }
        self.nodes.reserve_exact(nodes);
        for _ in 0..nodes {
            let [level, first, count, children] = [next(), next(), next(), next()];
            let mut c = [0.0f32; 6];
            for x in &mut c {
                *x = f32::from_bits(next());
            }
            let slots: [u32; MAX_SURFEL_CHILDREN] = std::array::from_fn(|_| next());
            if children as usize > MAX_SURFEL_CHILDREN {
                return Err(format!("a node has {children} children, more than 8"));
            }
            if slots[children as usize..].iter().any(|&s| s != NO_CHILD) {
                return Err("a node's unused child slots are not 0xFFFFFFFF".into());
            }
            self.nodes.push(SurfelNode {
                level,
                bounds: Aabb::new(Vec3::new(c[0], c[1], c[2]), Vec3::new(c[3], c[4], c[5])),
                first,
                count,
                children: slots[..children as usize].to_vec(),
            });
        }
        self.words = (0..surfels * SURFEL_WORDS).map(|_| next()).collect();
        let voxels = self
            .density
            .dims
            .iter()
            .map(|&d| d as usize)
            .product::<usize>();
        self.density.sigma = (0..voxels).map(|_| f32::from_bits(next())).collect();
        self.roots = Self::roots_of(&self.nodes, levels);
        match self.problem() {
            Some(p) => Err(p),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_surfel_survives_its_packing_within_its_steps() {
        let (qmin, qsize) = (Vec3::new(-2.0, 0.0, -3.0), Vec3::new(4.0, 9.0, 6.0));
        for k in 0..200u32 {
            let t = k as f32 / 199.0;
            let s = Surfel {
                position: qmin + qsize * Vec3::new(t, (t * 7.3).fract(), (t * 3.1).fract()),
                normal: Vec3::new((t * 9.0).sin(), (t * 5.0).cos(), t - 0.5).normalize(),
                albedo: Vec3::new(t, 1.0 - t, 0.5 * t),
                foliage: k.is_multiple_of(3),
                coverage: t.max(1.0 / 127.0),
                openness: 1.0 - t,
            };
            let u = unpack_surfel(pack_surfel(&s, qmin, qsize), qmin, qsize);
            let step = qsize / POSITION_STEPS;
            assert!(
                ((u.position - s.position).abs() - 0.51 * step).max_element() <= 0.0,
                "{k}"
            );
            assert!(
                u.normal.dot(s.normal) > 0.999,
                "{k}: {} vs {}",
                u.normal,
                s.normal
            );
            assert!((u.albedo - s.albedo).abs().max_element() < 0.01, "{k}");
            assert_eq!(u.foliage, s.foliage);
            assert!(
                (u.coverage - s.coverage).abs() <= 0.5 / COVERAGE_STEPS + 1e-6,
                "{k}"
            );
            assert!(
                (u.openness - s.openness).abs() <= 0.5 / OPENNESS_STEPS + 1e-6,
                "{k}"
            );
        }
    }
}
