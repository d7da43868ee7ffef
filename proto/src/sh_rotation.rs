//! Rotation of SH coefficients (orders 1 and 2, the [`crate::sh`] convention), and the rotation
//! matrix of a unit quaternion.
//!
//! A rotation `R` (row-major `r[i][j]`, acting on column vectors) turns the coefficients of `f`
//! into those of the rotated function `g(ω) = f(Rᵀ ω)`. Band 0 is invariant; band 1 (Sloan
//! order `y, z, x`) transforms as the vector `(c₃, c₁, c₂)`; band 2 is rotated by the 5×5 matrix
//! `A⁻¹ B`, where `A[k][m] = Y₂ₘ(ω_k)` and `B[k][m] = Y₂ₘ(Rᵀ ω_k)` at five fixed directions
//! `ω_k` for which `A` is invertible (a rotated band-2 function is again band-2, so matching it
//! at five points determines it exactly).
//!
//! Invariant: [`ShRotation::apply`] is exact up to rounding for any proper rotation; rotating
//! by `R` and then by `Rᵀ` returns the input.

use crate::sh::{sh_basis, SH_COEFFS};

/// Row-major rotation matrix of the unit quaternion `[x, y, z, w]` (the convention of
/// [`crate::scene::rotate`]: `R v` equals `rotate(q, v)`). The quaternion is normalised here;
/// a zero or non-finite one gives the identity.
pub fn quaternion_matrix(q: [f64; 4]) -> [[f64; 3]; 3] {
    let len = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    if !(len.is_finite() && len > 0.0) {
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    let [x, y, z, w] = q.map(|c| c / len);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - z * w),
            2.0 * (x * z + y * w),
        ],
        [
            2.0 * (x * y + z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - x * w),
        ],
        [
            2.0 * (x * z - y * w),
            2.0 * (y * z + x * w),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// Transpose (the inverse of a rotation).
pub fn transpose(r: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| r[j][i]))
}

/// `r · v`.
pub fn mul_vec(r: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2])
}

/// The per-band matrices that rotate SH coefficients by one rotation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShRotation {
    /// Band 1 in Sloan order (`y, z, x`): `c'[1 + i] = Σ_j band1[i][j] c[1 + j]`.
    pub band1: [[f64; 3]; 3],
    /// Band 2: `c'[4 + i] = Σ_j band2[i][j] c[4 + j]`.
    pub band2: [[f64; 5]; 5],
}

/// The five fixed directions of the band-2 fit (A is invertible at them).
fn fit_directions() -> [[f64; 3]; 5] {
    let h = std::f64::consts::FRAC_1_SQRT_2;
    [
        [1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
        [h, h, 0.0],
        [h, 0.0, h],
        [0.0, h, h],
    ]
}

fn band2_at(d: [f64; 3]) -> [f64; 5] {
    let y = sh_basis(d);
    [y[4], y[5], y[6], y[7], y[8]]
}

/// Inverse of a 5×5 matrix by Gauss–Jordan with partial pivoting (only called on the fixed,
/// well-conditioned fit matrix).
fn invert5(a: [[f64; 5]; 5]) -> [[f64; 5]; 5] {
    let mut m = a;
    let mut inv = [[0.0; 5]; 5];
    for (i, row) in inv.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for col in 0..5 {
        let pivot = (col..5)
            .max_by(|&p, &q| m[p][col].abs().total_cmp(&m[q][col].abs()))
            .unwrap_or(col);
        m.swap(col, pivot);
        inv.swap(col, pivot);
        let p = m[col][col];
        for k in 0..5 {
            m[col][k] /= p;
            inv[col][k] /= p;
        }
        for row in 0..5 {
            if row != col {
                let f = m[row][col];
                for k in 0..5 {
                    m[row][k] -= f * m[col][k];
                    inv[row][k] -= f * inv[col][k];
                }
            }
        }
    }
    inv
}

impl ShRotation {
    /// The SH rotation that maps the coefficients of `f` to those of `g(ω) = f(Rᵀ ω)`.
    pub fn new(r: &[[f64; 3]; 3]) -> ShRotation {
        // Sloan band-1 order y, z, x → world axes 1, 2, 0.
        let axis = [1usize, 2, 0];
        let band1 = std::array::from_fn(|i| std::array::from_fn(|j| r[axis[i]][axis[j]]));
        let rt = transpose(r);
        let dirs = fit_directions();
        let a: [[f64; 5]; 5] = std::array::from_fn(|k| band2_at(dirs[k]));
        let b: [[f64; 5]; 5] = std::array::from_fn(|k| band2_at(mul_vec(&rt, dirs[k])));
        let a_inv = invert5(a);
        let band2 = std::array::from_fn(|i| {
            std::array::from_fn(|j| (0..5).map(|k| a_inv[i][k] * b[k][j]).sum())
        });
        ShRotation { band1, band2 }
    }

    /// Rotates `c` in place: 1, 4 or 9 coefficients (orders 0, 1, 2); other lengths rotate
    /// their complete bands only (a partial band is left as it is).
    pub fn apply(&self, c: &mut [f64]) {
        if c.len() >= 4 {
            let v = [c[1], c[2], c[3]];
            for i in 0..3 {
                c[1 + i] = (0..3).map(|j| self.band1[i][j] * v[j]).sum();
            }
        }
        if c.len() >= SH_COEFFS {
            let v = [c[4], c[5], c[6], c[7], c[8]];
            for i in 0..5 {
                c[4 + i] = (0..5).map(|j| self.band2[i][j] * v[j]).sum();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sh::tests::sphere_points;
    use std::f64::consts::PI;

    fn eval(c: &[f64; SH_COEFFS], d: [f64; 3]) -> f64 {
        let y = sh_basis(d);
        (0..SH_COEFFS).map(|k| c[k] * y[k]).sum()
    }

    fn rotations() -> Vec<[[f64; 3]; 3]> {
        [
            [0.0, 0.0, 0.0, 1.0],
            [0.3, -0.5, 0.2, 0.8],
            [0.0, 1.0, 0.0, 0.0],
            [0.7, 0.1, -0.4, -0.2],
        ]
        .into_iter()
        .map(quaternion_matrix)
        .collect()
    }

    const COEFFS: [f64; SH_COEFFS] = [1.0, -0.4, 0.7, 0.25, -0.3, 0.5, 0.8, -0.6, 0.35];

    #[test]
    fn quaternion_matrix_agrees_with_scene_rotate() {
        let q = [0.3, -0.5, 0.2, 0.8];
        let n = q.iter().map(|x: &f64| x * x).sum::<f64>().sqrt();
        let qn = q.map(|x| x / n);
        let r = quaternion_matrix(q);
        for v in [[1.0, 0.0, 0.0], [0.2, -0.7, 1.5]] {
            let a = mul_vec(&r, v);
            let b = crate::scene::rotate(qn, v);
            for k in 0..3 {
                assert!((a[k] - b[k]).abs() < 1e-12, "{a:?} vs {b:?}");
            }
        }
    }

    /// The rotated coefficients equal the numerical projection of the rotated function
    /// `f(Rᵀ ω)` onto the basis, and reconstruct it pointwise.
    #[test]
    fn rotation_matches_projecting_the_rotated_function() {
        let pts = sphere_points(40000);
        let w = 4.0 * PI / pts.len() as f64;
        for r in rotations() {
            let rt = transpose(&r);
            let mut rotated = COEFFS;
            ShRotation::new(&r).apply(&mut rotated);
            let mut projected = [0.0; SH_COEFFS];
            for d in &pts {
                let f = eval(&COEFFS, mul_vec(&rt, *d));
                let y = sh_basis(*d);
                for k in 0..SH_COEFFS {
                    projected[k] += w * f * y[k];
                }
            }
            for k in 0..SH_COEFFS {
                assert!(
                    (rotated[k] - projected[k]).abs() < 2e-3,
                    "coefficient {k}: {} vs {}",
                    rotated[k],
                    projected[k]
                );
            }
            for d in sphere_points(64) {
                let g = eval(&rotated, d);
                let f = eval(&COEFFS, mul_vec(&rt, d));
                assert!((g - f).abs() < 1e-12, "{g} vs {f}");
            }
        }
    }

    #[test]
    fn rotating_there_and_back_is_the_identity() {
        for r in rotations() {
            let mut c = COEFFS;
            ShRotation::new(&r).apply(&mut c);
            ShRotation::new(&transpose(&r)).apply(&mut c);
            for k in 0..SH_COEFFS {
                assert!(
                    (c[k] - COEFFS[k]).abs() < 1e-12,
                    "{k}: {} vs {}",
                    c[k],
                    COEFFS[k]
                );
            }
            // Order 1 alone (4 coefficients) round-trips too and keeps its length.
            let mut c4 = [COEFFS[0], COEFFS[1], COEFFS[2], COEFFS[3]];
            ShRotation::new(&r).apply(&mut c4);
            ShRotation::new(&transpose(&r)).apply(&mut c4);
            for k in 0..4 {
                assert!((c4[k] - COEFFS[k]).abs() < 1e-12);
            }
        }
    }
}
