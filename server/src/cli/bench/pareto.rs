//! The Pareto front of a set of (cost, error) points, both to be minimised: the settings a user
//! should choose from, since every other point is beaten on both by one of them.
//!
//! Invariant: a point with a non-finite coordinate is never on the front and never dominates.

/// `front[i]` is true when no other point is at least as good in both coordinates and strictly
/// better in one. Equal points are all on the front.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<bool> {
    let finite = |p: &(f64, f64)| p.0.is_finite() && p.1.is_finite();
    points
        .iter()
        .map(|p| {
            finite(p)
                && !points
                    .iter()
                    .any(|q| finite(q) && q.0 <= p.0 && q.1 <= p.1 && (q.0 < p.0 || q.1 < p.1))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_made_front() {
        // (cost, error)
        let points = [
            (1.0, 0.50),     // front: cheapest
            (2.0, 0.20),     // front
            (3.0, 0.25),     // dominated by (2, 0.20)
            (4.0, 0.05),     // front
            (4.0, 0.05),     // front: equal to the one above
            (5.0, 0.05),     // dominated: same error, more cost
            (8.0, 0.01),     // front: most accurate
            (0.5, f64::NAN), // never on the front
            (9.0, 0.30),     // dominated
        ];
        let front = pareto_front(&points);
        assert_eq!(
            front,
            [true, true, false, true, true, false, true, false, false]
        );
    }

    #[test]
    fn empty_and_single() {
        assert!(pareto_front(&[]).is_empty());
        assert_eq!(pareto_front(&[(1.0, 1.0)]), [true]);
        assert_eq!(pareto_front(&[(f64::INFINITY, 1.0)]), [false]);
    }
}
