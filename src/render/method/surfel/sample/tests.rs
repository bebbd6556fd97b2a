//! The LDC tree's tests: a flat quad's levels, and a real tree's levels keeping its
//! silhouettes and colour.

use super::*;
use crate::model::Vertex;

/// A flat square of side `side` (m) in the plane z = 0, facing +z, of `color`.
fn quad(side: f32, color: Vec3) -> TreeModel {
    let mut mesh = Mesh::default();
    let n = Vec3::Z;
    let h = side / 2.0;
    for p in [
        Vec3::new(-h, 0.0, 0.0),
        Vec3::new(h, 0.0, 0.0),
        Vec3::new(h, side, 0.0),
        Vec3::new(-h, side, 0.0),
    ] {
        mesh.vertices.push(Vertex::new(p, n, color, 0.0));
    }
    mesh.indices = vec![0, 1, 2, 0, 2, 3];
    let bounds = Aabb::new(Vec3::new(-h, 0.0, -0.01), Vec3::new(h, side, 0.01));
    TreeModel {
        name: "quad".into(),
        foliage: crate::model::FoliageKind::Leaves,
        foliage_per_twig: 0,
        twig: Mesh::default(),
        branch_limb: Mesh::default(),
        branch_twigs: Vec::new(),
        trunk: mesh,
        tree_branches: Vec::new(),
        tree_twigs: Vec::new(),
        twig_bounds: Aabb::EMPTY,
        branch_bounds: Aabb::EMPTY,
        tree_bounds: bounds,
        surfaces: None,
        levels_note: None,
        variant: 0,
    }
}

#[test]
fn a_quad_is_covered_at_every_level_with_its_colour() {
    let color = Vec3::new(0.2, 0.5, 0.1);
    let tree = quad(4.0, color);
    let s = sample_tree(&tree, 10_000, 0.0);
    // About 10,000 surfels at level 0 (all in the LDI along z).
    let l0 = s.set.per_level[0];
    assert!((8_000..=12_000).contains(&l0), "{l0}");
    assert!(s.set.levels() >= 3, "{}", s.set.levels());
    assert_eq!(s.set.roots.len(), 1);
    for node in &s.set.nodes {
        for x in &s.surfels[node.first as usize..(node.first + node.count) as usize] {
            assert!((x.albedo - color).abs().max_element() < 1e-5);
            assert!(x.position.z.abs() < 1e-5);
            assert!(x.normal.abs_diff_eq(Vec3::Z, 1e-5));
            assert!(node.bounds.contains(x.position));
        }
    }
    // Each level covers the quad: every cell of its spacing holds a surfel.
    for l in 0..s.set.levels() as u32 {
        let r = s.set.spacing(l);
        let n = (4.0 / r).floor() as i32;
        let mut covered = std::collections::HashSet::new();
        for node in s.set.nodes.iter().filter(|n| n.level == l) {
            for x in &s.surfels[node.first as usize..(node.first + node.count) as usize] {
                covered.insert((((x.position.x + 2.0) / r) as i32, (x.position.y / r) as i32));
            }
        }
        for i in 0..n {
            for j in 0..n {
                assert!(covered.contains(&(i, j)), "level {l}: cell {i},{j} empty");
            }
        }
    }
}

/// Per level: how much of the tree's silhouette along each axis its surfels cover, as
/// the splatting draws a level whose spacing is a pixel (on a grid of the level's
/// spacing, each surfel leaving open 1 - its coverage seen along the axis), summed over
/// the three axes in m², and their coverage-weighted mean albedo.
fn level_totals(s: &SurfelTree) -> Vec<(f32, Vec3)> {
    (0..s.set.levels() as u32)
        .map(|l| {
            let r = s.set.spacing(l);
            let cell = r;
            let mut area = 0.0f32;
            let mut colour = Vec3::ZERO;
            let mut weight = 0.0f32;
            for axis in 0..3 {
                let (a, b) = across(axis);
                let mut open: HashMap<(i32, i32), f32> = HashMap::new();
                for node in s.set.nodes.iter().filter(|n| n.level == l) {
                    for x in &s.surfels[node.first as usize..(node.first + node.count) as usize] {
                        let n = x.normal.abs();
                        let seen = n[axis] / n.max_element().max(0.3);
                        let k = (r * r) / (cell * cell) * seen;
                        let key = (
                            ((x.position[a] - s.set.bounds.min[a]) / cell) as i32,
                            ((x.position[b] - s.set.bounds.min[b]) / cell) as i32,
                        );
                        *open.entry(key).or_insert(1.0) *= (1.0 - x.coverage).powf(k);
                        colour += x.albedo * x.coverage;
                        weight += x.coverage;
                    }
                }
                area += open.values().map(|o| 1.0 - o).sum::<f32>() * cell * cell;
            }
            (area, colour / weight.max(1e-9))
        })
        .collect()
}

#[test]
fn parent_levels_keep_a_trees_coverage_and_mean_colour() {
    for name in ["fir", "broadleaf"] {
        let params = crate::model::preset(name).unwrap();
        let tree = TreeModel::generate(&params, 7).unwrap();
        let s = sample_tree(&tree, 60_000, 0.0);
        let totals = level_totals(&s);
        assert_eq!(s.set.gains[0], 1.0, "{name}");
        assert!(
            s.set.gains.iter().all(|g| (1.0..=16.0).contains(g)),
            "{name}: {:?}",
            s.set.gains
        );
        let (area0, colour0) = totals[0];
        // The levels down to one block: the coarsest is a single root.
        assert!(s.set.levels() >= 4, "{name}: {} levels", s.set.levels());
        assert_eq!(s.set.roots.len(), 1, "{name}");
        // Every node's surfels lie in its bounds; children are one level finer.
        for n in &s.set.nodes {
            for x in &s.surfels[n.first as usize..(n.first + n.count) as usize] {
                assert!(n.bounds.contains(x.position), "{name}");
            }
            for &c in &n.children {
                assert_eq!(s.set.nodes[c as usize].level + 1, n.level, "{name}");
            }
        }
        for (l, (area, colour)) in totals.iter().enumerate() {
            eprintln!(
                "{name} level {l} ({:.3} m): {} surfels, silhouettes {:.2} m² (level 0: {area0:.2}), mean albedo {colour:.3}",
                s.set.spacing(l as u32),
                s.set.per_level[l],
                area
            );
            // The silhouettes along the three axes as the surfels of each level cover
            // them. Merged as they come (a merged surfel covering the union of its
            // parts), levels 1, 2, 3 kept 0.98, 0.94, 0.86 of level 0's on the fir at a
            // 60,000 budget (0.96, 0.92, 0.90 on the broadleaf) and the coarsest, one
            // block for the tree, 0.62 (0.78): deep crowns overlap most. Each level's
            // gain (`gains`) makes up for it, as measured on the LDIs' own pixels;
            // measured here on a grid of where the merged surfels lie (a big surfel's
            // cell straddles the grid's), levels 1-3 land within 0.97-1.08 of level 0,
            // the coarser ones within 1.23 (the colour within 0.001).
            let (lo, hi) = if l <= 3 { (0.9, 1.12) } else { (0.8, 1.35) };
            assert!(
                *area > lo * area0 && *area < hi * area0,
                "{name} level {l}: {area} against {area0}"
            );
            assert!(
                (*colour - colour0).abs().max_element() < 0.005,
                "{name} level {l}: {colour} against {colour0}"
            );
        }
    }
}
