//! Comparing two per-texel RGB vectors (direct or indirect light, one value per layout texel):
//! how engines, tools and tests say how far one lighting is from another.
//!
//! Units: a ratio, dimensionless. Sums are in f64 so a large level keeps its digits.

/// Relative L2 of `ours` against `reference` over every texel and channel:
/// `sqrt(Σ (ours − reference)² / Σ reference²)` (texels past the shorter vector are ignored;
/// an all-zero reference gives infinity, or NaN when `ours` is zero too).
pub fn relative_l2(ours: &[[f32; 3]], reference: &[[f32; 3]]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in ours.iter().zip(reference) {
        for c in 0..3 {
            num += (x[c] as f64 - y[c] as f64).powi(2);
            den += (y[c] as f64).powi(2);
        }
    }
    (num / den).sqrt()
}

/// Relative L1 of `ours` against `reference` over every texel and channel:
/// `Σ |ours − reference| / Σ |reference|` (the norm the feedback tolerance and its lag
/// estimate, `Runtime::feedback_lag`, are in; the same edge cases as [`relative_l2`]).
pub fn relative_l1(ours: &[[f32; 3]], reference: &[[f32; 3]]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in ours.iter().zip(reference) {
        for c in 0..3 {
            num += (x[c] as f64 - y[c] as f64).abs();
            den += (y[c] as f64).abs();
        }
    }
    num / den
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_l1_sums_absolute_differences_over_absolute_light() {
        let reference = vec![[1.0, 2.0, 3.0], [0.5, 0.0, -1.5]];
        let ours: Vec<[f32; 3]> = reference.iter().map(|v| v.map(|x| 1.1 * x)).collect();
        assert!((relative_l1(&ours, &reference) - 0.1).abs() < 1e-6);
        // One texel off by 0.8 out of 8 in all.
        let mut off = reference.clone();
        off[1][1] = -0.8;
        assert!((relative_l1(&off, &reference) - 0.1).abs() < 1e-6);
        assert_eq!(relative_l1(&reference, &reference), 0.0);
        assert!(relative_l1(&ours, &[[0.0; 3]; 2]).is_infinite());
    }

    #[test]
    fn relative_l2_of_a_scaled_vector_is_the_scale_error() {
        let reference = vec![[1.0, 2.0, 3.0], [0.5, 0.0, -1.0]];
        let ours: Vec<[f32; 3]> = reference.iter().map(|v| v.map(|x| 1.1 * x)).collect();
        assert!((relative_l2(&ours, &reference) - 0.1).abs() < 1e-6);
        assert_eq!(relative_l2(&reference, &reference), 0.0);
        assert!(relative_l2(&ours, &[[0.0; 3]; 2]).is_infinite());
    }
}
