//! The Pareto front of (cost, error) points, both to be minimised: the configurations that
//! no other configuration beats on both speed and accuracy at once.

/// Indices of the points on the Pareto front of `points` = (cost ms, error), sorted by
/// cost (then error, then index). A point is on the front when no other point is at least
/// as good in both and strictly better in one. Exact duplicates of a front point are all
/// kept (neither dominates the other). Points with a NaN coordinate are never on the front
/// and never dominate.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..points.len())
        .filter(|&i| !points[i].0.is_nan() && !points[i].1.is_nan())
        .collect();
    order.sort_by(|&a, &b| {
        let (pa, pb) = (points[a], points[b]);
        pa.0.total_cmp(&pb.0)
            .then(pa.1.total_cmp(&pb.1))
            .then(a.cmp(&b))
    });
    // Swept by increasing cost: a point is kept when its error is below every error seen at
    // a strictly lower cost, and no lower error exists at its own cost (the sort puts the
    // lowest error of each cost first).
    let mut front = Vec::new();
    let mut best = f64::INFINITY;
    let mut last: Option<(f64, f64)> = None;
    for i in order {
        let p = points[i];
        if last == Some(p) {
            front.push(i);
        } else if p.1 < best {
            front.push(i);
            best = p.1;
            last = Some(p);
        }
    }
    front
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hand_made_set_keeps_only_the_undominated_points_in_cost_order() {
        let points = [
            (10.0, 0.05), // 0: front (slowest, most accurate)
            (2.0, 0.30),  // 1: front (fastest)
            (5.0, 0.10),  // 2: front
            (6.0, 0.12),  // 3: dominated by 2
            (5.0, 0.20),  // 4: same cost as 2, worse error
            (2.0, 0.30),  // 5: duplicate of 1: kept with it
            (3.0, 0.30),  // 6: same error as 1, dearer
            (12.0, 0.05), // 7: same error as 0, dearer
            (f64::NAN, 0.0),
        ];
        assert_eq!(pareto_front(&points), vec![1, 5, 2, 0]);
    }

    #[test]
    fn empty_and_single_sets() {
        assert!(pareto_front(&[]).is_empty());
        assert_eq!(pareto_front(&[(1.0, 1.0)]), vec![0]);
    }

    #[test]
    fn a_strictly_improving_chain_is_all_front() {
        let points: Vec<_> = (0..5)
            .map(|i| (f64::from(i), 1.0 / f64::from(i + 1)))
            .collect();
        assert_eq!(pareto_front(&points), vec![0, 1, 2, 3, 4]);
        let worse: Vec<_> = (0..5).map(|i| (f64::from(i), f64::from(i))).collect();
        assert_eq!(pareto_front(&worse), vec![0]);
    }
}
