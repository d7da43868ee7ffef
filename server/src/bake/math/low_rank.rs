//! Truncated SVD with ranks chosen from a tolerance, in f64 with faer.
//!
//! `A ≈ U_k Σ_k V_kᵀ` with `A` m×n, `U_k` m×k, `Σ_k` k×k, `V_k` n×k. The rank `k` is the smallest
//! that keeps `Σ_{i<k} σ_i² ≥ (1 − tolerance) · Σ_i σ_i²`, and singular values below
//! `RELATIVE_FLOOR · σ_max` are always dropped, so nothing downstream ever divides by a
//! numerically zero singular value.
//!
//! [`truncated_column_basis`] gives `U_k` alone (through the Gram matrix when large), and
//! [`energy_rank`] gives the rank alone, from the Gram matrix's eigenvalues when the matrix is
//! large (the prescreen that refuses a factorisation before its vectors are paid for).
//!
//! Invariant: runs sequentially (faer `Par::Seq`) so results are bit-identical at any thread
//! count; callers parallelise across independent decompositions instead.

use faer::{Mat, MatRef, Par};

/// Singular values below this fraction of the largest are never kept.
pub const RELATIVE_FLOOR: f64 = 1e-9;

/// A truncated SVD.
pub struct TruncatedSvd {
    /// m × k.
    pub u: Mat<f64>,
    /// k singular values, descending.
    pub s: Vec<f64>,
    /// n × k.
    pub v: Mat<f64>,
    /// All singular values (for reports).
    pub all_singular_values: Vec<f64>,
    /// Fraction of energy dropped: Σ_{i≥k} σ_i² / Σ σ_i².
    pub dropped_energy: f64,
}

/// Why a decomposition failed.
#[derive(Clone, Debug, thiserror::Error)]
pub enum LowRankError {
    #[error("SVD of a {rows}×{cols} matrix did not converge")]
    NoConvergence { rows: usize, cols: usize },
    #[error("matrix has a non-finite entry")]
    NonFinite,
}

/// Rank that keeps `1 − tolerance` of the energy (at least 1 if any σ is above the floor).
pub fn rank_for_energy(singular_values: &[f64], tolerance: f64) -> usize {
    let total: f64 = singular_values.iter().map(|s| s * s).sum();
    let max = singular_values.first().copied().unwrap_or(0.0);
    if total <= 0.0 || max <= 0.0 {
        return 0;
    }
    let mut kept = 0.0;
    for (k, s) in singular_values.iter().enumerate() {
        if *s < RELATIVE_FLOOR * max {
            return k;
        }
        kept += s * s;
        if kept >= (1.0 - tolerance) * total {
            return k + 1;
        }
    }
    singular_values.len()
}

/// Thin SVD of `a`, truncated by `tolerance`.
pub fn truncated_svd(a: MatRef<'_, f64>, tolerance: f64) -> Result<TruncatedSvd, LowRankError> {
    let (m, n) = (a.nrows(), a.ncols());
    check_finite(a)?;
    if m == 0 || n == 0 {
        return Ok(TruncatedSvd {
            u: Mat::zeros(m, 0),
            s: vec![],
            v: Mat::zeros(n, 0),
            all_singular_values: vec![],
            dropped_energy: 0.0,
        });
    }
    faer::set_global_parallelism(Par::Seq);
    let (u, all, v) = thin_svd(a)?;
    let k = rank_for_energy(&all, tolerance);
    let total: f64 = all.iter().map(|s| s * s).sum();
    let kept: f64 = all[..k].iter().map(|s| s * s).sum();
    Ok(TruncatedSvd {
        u: u.subcols(0, k).to_owned(),
        s: all[..k].to_vec(),
        v: v.subcols(0, k).to_owned(),
        dropped_energy: if total > 0.0 {
            ((total - kept) / total).max(0.0)
        } else {
            0.0
        },
        all_singular_values: all,
    })
}

/// An orthonormal basis of `a`'s dominant column space: the left singular vectors
/// [`truncated_svd`] keeps (same rank rule), and the fraction of energy dropped. Only the
/// basis is wanted, so a matrix whose short side has at least [`GRAM_MIN_SIDE`] values is
/// taken through its Gram matrix on the short side: for `m ≥ n`, the eigenvectors `V_k` of
/// `AᵀA` give `A V_k`, orthonormalised by a thin QR; for `m < n`, the eigenvectors of `AAᵀ`
/// are the basis. About four times faster than the SVD on a clutter object's prior (1,536
/// texels × 761 lights: 0.31 s). The eigenvalues carry an absolute rounding error of about
/// `ε · σ_max²`, so a kept direction whose `σ²` is far above that (any a tolerance of 1e-6 or
/// more keeps) is the SVD's to rounding; the rank may differ from the SVD's by one where a
/// value lies within rounding of the energy threshold. Falls back to the SVD when the
/// eigendecomposition fails or is not finite.
pub fn truncated_column_basis(
    a: MatRef<'_, f64>,
    tolerance: f64,
) -> Result<(Mat<f64>, f64), LowRankError> {
    let (m, n) = (a.nrows(), a.ncols());
    check_finite(a)?;
    if m.min(n) < GRAM_MIN_SIDE {
        let svd = truncated_svd(a, tolerance)?;
        return Ok((svd.u, svd.dropped_energy));
    }
    faer::set_global_parallelism(Par::Seq);
    let tall = m >= n;
    let gram = short_side_gram(a);
    let basis = gram
        .self_adjoint_eigen(faer::Side::Lower)
        .ok()
        .and_then(|eig| {
            // Ascending λ = σ² (rounding can leave a zero slightly negative).
            let side = gram.nrows();
            let lambda: Vec<f64> = (0..side).rev().map(|i| eig.S()[i].max(0.0)).collect();
            let s: Vec<f64> = lambda.iter().map(|l| l.sqrt()).collect();
            if !s.iter().all(|x| x.is_finite()) {
                return None;
            }
            let k = rank_for_energy(&s, tolerance);
            let vectors = Mat::from_fn(side, k, |i, j| eig.U()[(i, side - 1 - j)]);
            let u = if tall {
                let w = a * &vectors;
                w.qr().compute_thin_Q()
            } else {
                vectors
            };
            let total: f64 = lambda.iter().sum();
            let kept: f64 = lambda[..k].iter().sum();
            let dropped = if total > 0.0 {
                ((total - kept) / total).max(0.0)
            } else {
                0.0
            };
            is_finite(u.as_ref()).then_some((u, dropped))
        });
    match basis {
        Some(b) => Ok(b),
        None => {
            let svd = truncated_svd(a, tolerance)?;
            Ok((svd.u, svd.dropped_energy))
        }
    }
}

/// The thin SVD `a = U Σ Vᵀ` (singular values descending), checked: faer's divide-and-conquer
/// SVD can return NaN for a finite, well-scaled input (measured: a 320 × 526 transport
/// compaction of a generated 320-block level, exactly rank-deficient; its transpose and its
/// scalings by 2 and ½ fail alike). Then the SVD is taken of the triangular factor of a QR
/// decomposition on the matrix's long side ([`svd_by_qr`]), which has the same singular values
/// and vectors. A result that is still not finite is an error, never a NaN handed on.
fn thin_svd(a: MatRef<'_, f64>) -> Result<(Mat<f64>, Vec<f64>, Mat<f64>), LowRankError> {
    let (m, n) = (a.nrows(), a.ncols());
    let failed = LowRankError::NoConvergence { rows: m, cols: n };
    let svd = a.thin_svd().map_err(|_| failed.clone())?;
    let s: Vec<f64> = (0..m.min(n)).map(|i| svd.S()[i]).collect();
    if s.iter().all(|x| x.is_finite()) && is_finite(svd.U()) && is_finite(svd.V()) {
        return Ok((svd.U().to_owned(), s, svd.V().to_owned()));
    }
    let (u, s, v) = svd_by_qr(a).ok_or(failed.clone())?;
    if s.iter().all(|x| x.is_finite()) && is_finite(u.as_ref()) && is_finite(v.as_ref()) {
        Ok((u, s, v))
    } else {
        Err(failed)
    }
}

/// The thin SVD of `a` through a QR decomposition on its long side: for `m ≥ n`, `a = Q R` and
/// `R = U' Σ Vᵀ` give `U = Q U'`; for `m < n`, `aᵀ = Q R` and `Rᵀ = U Σ Wᵀ` give `V = Q W`.
/// None when the small SVD fails.
fn svd_by_qr(a: MatRef<'_, f64>) -> Option<(Mat<f64>, Vec<f64>, Mat<f64>)> {
    let tall = a.nrows() >= a.ncols();
    let long = if tall {
        a.to_owned()
    } else {
        a.transpose().to_owned()
    };
    let qr = long.qr();
    let q = qr.compute_thin_Q();
    let r = qr.thin_R().to_owned();
    let small = if tall { r } else { r.transpose().to_owned() };
    let svd = small.thin_svd().ok()?;
    let s: Vec<f64> = (0..small.nrows().min(small.ncols()))
        .map(|i| svd.S()[i])
        .collect();
    Some(if tall {
        (&q * svd.U(), s, svd.V().to_owned())
    } else {
        (svd.U().to_owned(), s, &q * svd.V())
    })
}

fn is_finite(m: MatRef<'_, f64>) -> bool {
    (0..m.ncols()).all(|j| (0..m.nrows()).all(|i| m[(i, j)].is_finite()))
}

fn check_finite(a: MatRef<'_, f64>) -> Result<(), LowRankError> {
    for j in 0..a.ncols() {
        for i in 0..a.nrows() {
            if !a[(i, j)].is_finite() {
                return Err(LowRankError::NonFinite);
            }
        }
    }
    Ok(())
}

/// The rank [`truncated_svd`] would keep, from the singular values alone: no singular vectors
/// are formed, which costs a fraction of the decomposition. For deciding that a matrix is not
/// worth factoring before paying for its vectors; the two ranks agree up to rounding in the
/// singular values (a value within rounding of the energy threshold can move the rank by one).
///
/// A matrix whose short side has at least [`GRAM_MIN_SIDE`] values takes its squared singular
/// values as the eigenvalues of its Gram matrix on the short side (`AᵀA` or `AAᵀ`), summed over
/// the nonzeros of each row or column when the matrix is mostly zeros (the exact gather's ray-hit
/// fractions): a tridiagonal reduction of the short side instead of a bidiagonal one of the
/// whole matrix (measured on the maze's refused gather ranges: 2560 × 1280 at 24% nonzero
/// 1.13 s → 0.45 s, 1717 × 1280 at 4% 0.33 s → 0.30 s). An eigenvalue carries an absolute rounding error of about
/// `ε · σ_max²`, far below any energy fraction a tolerance names, so the rank agrees with the
/// singular values' up to the same one-off ties.
pub fn energy_rank(a: MatRef<'_, f64>, tolerance: f64) -> Result<usize, LowRankError> {
    let (m, n) = (a.nrows(), a.ncols());
    check_finite(a)?;
    if m == 0 || n == 0 {
        return Ok(0);
    }
    faer::set_global_parallelism(Par::Seq);
    if m.min(n) >= GRAM_MIN_SIDE {
        let gram = short_side_gram(a);
        if let Ok(mut eigenvalues) = gram.self_adjoint_eigenvalues(faer::Side::Lower) {
            if eigenvalues.iter().all(|x| x.is_finite()) {
                // Ascending λ = σ² (rounding can leave a zero slightly negative).
                eigenvalues.reverse();
                let s: Vec<f64> = eigenvalues.iter().map(|l| l.max(0.0).sqrt()).collect();
                return Ok(rank_for_energy(&s, tolerance));
            }
        }
    }
    let s = a
        .singular_values()
        .map_err(|_| LowRankError::NoConvergence { rows: m, cols: n })?;
    if s.iter().all(|x| x.is_finite()) {
        Ok(rank_for_energy(&s, tolerance))
    } else {
        // As in `thin_svd`: a result that is not finite is taken again through a QR.
        Ok(rank_for_energy(&thin_svd(a)?.1, tolerance))
    }
}

/// Whether [`energy_rank`]`(a, tolerance)` is surely above `m`, proven from part of the Gram
/// matrix; false when this part does not prove it (the rank may still be above `m`).
///
/// The proof: the rank exceeds `m` exactly when the energy beyond the `m` largest singular values
/// is above `tolerance · ‖A‖_F²`. A principal submatrix `G_S` of the Gram matrix `G` on the short
/// side (its `s` heaviest lines, `s = m +` [`PROOF_EXTRA_RANK`]) has eigenvalues interlacing
/// `G`'s (Cauchy: `λ_i(G) ≥ λ_i(G_S)`), so `Σ_{i>m} λ_i(G) ≥ Σ_{m<i≤s} λ_i(G_S)`: the `s − m`
/// smallest eigenvalues of `G_S` bound the energy beyond `m` from below. It is taken as proof
/// when that bound is at least twice `tolerance · ‖A‖_F²`, a margin far above rounding
/// (`ε · σ_max²` per eigenvalue), so whatever [`energy_rank`] computes is then above `m` too
/// (and no singular value beyond `m` falls under [`RELATIVE_FLOOR`]).
///
/// Costs `s²` products per long-side line and an `s × s` eigenvalue problem, against `n²` and
/// `n × n` for [`energy_rank`] (`n` the short side): the refusal of a noise-like matrix (most
/// of the exact gather's ranges) without its whole spectrum. Errors as [`energy_rank`] does on
/// a non-finite entry.
pub fn rank_surely_exceeds(
    a: MatRef<'_, f64>,
    tolerance: f64,
    m: usize,
) -> Result<bool, LowRankError> {
    check_finite(a)?;
    // Lines run along the long side; the Gram matrix is over the short side's n indices.
    let a = if a.nrows() >= a.ncols() {
        a
    } else {
        a.transpose()
    };
    let (lines, n) = (a.nrows(), a.ncols());
    let s = m + PROOF_EXTRA_RANK.max(m / 4);
    if s > n || lines == 0 {
        return Ok(false);
    }
    faer::set_global_parallelism(Par::Seq);
    let weight: Vec<f64> = (0..n)
        .map(|j| (0..lines).map(|i| a[(i, j)] * a[(i, j)]).sum())
        .collect();
    let total: f64 = weight.iter().sum();
    if total <= 0.0 {
        return Ok(false);
    }
    // The s heaviest indices (ties by index), in index order.
    let mut heaviest: Vec<usize> = (0..n).collect();
    heaviest.sort_by(|&x, &y| weight[y].total_cmp(&weight[x]).then(x.cmp(&y)));
    heaviest.truncate(s);
    heaviest.sort_unstable();
    let part = Mat::from_fn(lines, s, |i, j| a[(i, heaviest[j])]);
    let Ok(eigenvalues) =
        short_side_gram(part.as_ref()).self_adjoint_eigenvalues(faer::Side::Lower)
    else {
        return Ok(false);
    };
    // Ascending: the s − m smallest.
    let below: f64 = eigenvalues[..s - m].iter().map(|l| l.max(0.0)).sum();
    Ok(below.is_finite() && below >= 2.0 * tolerance * total)
}

/// Indices [`rank_surely_exceeds`] takes beyond the rank it proves (at least; a quarter of the
/// rank when that is more).
pub const PROOF_EXTRA_RANK: usize = 32;

/// Short side from which [`energy_rank`] works on the Gram matrix.
pub const GRAM_MIN_SIDE: usize = 64;

/// Below one nonzero in this many, [`short_side_gram`] sums over nonzeros; above, one dense
/// product is faster (measured on the maze's gather ranges: at 4% nonzero the sum takes 0.07 s
/// of a 1717 × 1280 range, at 24% the sum 1.07 s against the product's 0.13 s of 2560 × 1280).
const SPARSE_GRAM_DENSITY: f64 = 10.0;

/// The Gram matrix of `a` on its short side (`AᵀA` for a tall matrix, `AAᵀ` for a wide one),
/// lower triangle filled. Below one nonzero in [`SPARSE_GRAM_DENSITY`] it is summed over each
/// long-side line's nonzeros (`Σ nnz² / 2` products, in a fixed order); otherwise it is one
/// dense product.
fn short_side_gram(a: MatRef<'_, f64>) -> Mat<f64> {
    // Lines run along the long side; each is a vector over the short side.
    let a = if a.nrows() >= a.ncols() {
        a
    } else {
        a.transpose()
    };
    let (lines, n) = (a.nrows(), a.ncols());
    let nonzeros = (0..n)
        .map(|j| (0..lines).filter(|&i| a[(i, j)] != 0.0).count())
        .sum::<usize>();
    if SPARSE_GRAM_DENSITY * nonzeros as f64 >= (lines * n) as f64 {
        return a.transpose() * a;
    }
    // Column-major lower triangle: entry (j, k), j ≥ k, at k·n + j.
    let mut gram = vec![0.0f64; n * n];
    let mut line: Vec<(usize, f64)> = Vec::with_capacity(n);
    for i in 0..lines {
        line.clear();
        line.extend((0..n).map(|j| (j, a[(i, j)])).filter(|&(_, v)| v != 0.0));
        for (x, &(k, vk)) in line.iter().enumerate() {
            let column = &mut gram[k * n..(k + 1) * n];
            for &(j, vj) in &line[x..] {
                column[j] += vj * vk;
            }
        }
    }
    Mat::from_fn(n, n, |j, k| gram[k * n + j])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn truncation_error_equals_the_dropped_singular_values() {
        // A 40×30 matrix with known spectrum: σ_i = 2^-i.
        let m = 40;
        let n = 30;
        let q1 = orthonormal(m, n, 1);
        let q2 = orthonormal(n, n, 2);
        let sigma: Vec<f64> = (0..n).map(|i| 0.5f64.powi(i as i32)).collect();
        let a = with_spectrum(&q1, &sigma, &q2);
        let tol = 1e-4;
        let svd = truncated_svd(a.as_ref(), tol).unwrap();
        let k = svd.s.len();
        let total: f64 = sigma.iter().map(|s| s * s).sum();
        let dropped: f64 = sigma[k..].iter().map(|s| s * s).sum();
        assert!(
            dropped / total <= tol
                && sigma[k - 1..].iter().map(|s| s * s).sum::<f64>() / total > tol
        );
        // ‖A − U_k Σ_k V_kᵀ‖_F² equals the dropped energy (ε·√n tolerance).
        let approx = Mat::from_fn(m, n, |i, j| {
            (0..k)
                .map(|r| svd.u[(i, r)] * svd.s[r] * svd.v[(j, r)])
                .sum::<f64>()
        });
        let err: f64 = (0..m)
            .flat_map(|i| (0..n).map(move |j| (i, j)))
            .map(|(i, j)| (a[(i, j)] - approx[(i, j)]).powi(2))
            .sum();
        assert!(
            (err - dropped).abs() <= 1e-12 * (n as f64).sqrt(),
            "{err} vs {dropped}"
        );
        assert!((svd.dropped_energy - dropped / total).abs() < 1e-12);
    }

    /// The fallback's decomposition is the SVD: on tall and wide random matrices it gives
    /// faer's singular values and a factorisation that reconstructs the input.
    #[test]
    fn svd_by_qr_is_the_svd() {
        for (m, n) in [(40, 25), (25, 40), (30, 30)] {
            let a = Mat::from_fn(m, n, |i, j| ((i * 7 + j * 13) as f64 * 0.37).sin() + 0.1);
            let direct = a.thin_svd().unwrap();
            let (u, s, v) = svd_by_qr(a.as_ref()).unwrap();
            for (i, x) in s.iter().enumerate() {
                assert!(
                    (x - direct.S()[i]).abs() <= 1e-12 * direct.S()[0],
                    "σ_{i}: {x}"
                );
            }
            let us = Mat::from_fn(m, s.len(), |i, j| u[(i, j)] * s[j]);
            let back = &us * v.transpose();
            assert!((&back - &a).norm_l2() <= 1e-12 * a.norm_l2(), "{m}×{n}");
        }
    }

    /// A matrix on which faer's SVD returns NaN (a transport compaction of a generated
    /// 320-block level, `tests/data/svd_nan_320x526.f64.zst`: u32 rows, u32 cols, then f64
    /// values row by row, zstd): the truncated SVD comes out finite, keeps the energy its
    /// tolerance asks, and reconstructs the matrix to what it dropped.
    #[test]
    fn an_input_faer_returns_nan_for_is_decomposed() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../tests/data/svd_nan_320x526.f64.zst"
        );
        let bytes = zstd::decode_all(std::fs::File::open(path).unwrap()).unwrap();
        let (m, n) = (
            u32::from_le_bytes(bytes[0..4].try_into().unwrap()) as usize,
            u32::from_le_bytes(bytes[4..8].try_into().unwrap()) as usize,
        );
        let a = Mat::from_fn(m, n, |i, j| {
            let k = 8 + 8 * (i * n + j);
            f64::from_le_bytes(bytes[k..k + 8].try_into().unwrap())
        });
        faer::set_global_parallelism(Par::Seq);
        let raw = a.thin_svd().unwrap();
        assert!(
            (0..m.min(n)).any(|i| !raw.S()[i].is_finite()),
            "faer decomposes this matrix now: the fixture no longer tests the fallback"
        );
        let t = truncated_svd(a.as_ref(), 1e-3).unwrap();
        assert!(t.all_singular_values.iter().all(|s| s.is_finite()));
        assert!(t.dropped_energy <= 1e-3);
        let us = Mat::from_fn(m, t.s.len(), |i, j| t.u[(i, j)] * t.s[j]);
        let back = &us * t.v.transpose();
        let residual = (&back - &a).norm_l2() / a.norm_l2();
        assert!(
            residual <= (t.dropped_energy.sqrt() + 1e-12),
            "residual {residual}"
        );
        assert_eq!(energy_rank(a.as_ref(), 1e-3).unwrap(), t.s.len());
    }

    #[test]
    fn rank_deficient_input_never_keeps_zero_singular_values() {
        let a = Mat::from_fn(10, 6, |i, j| ((i + 1) * (j + 1)) as f64); // rank 1
        let svd = truncated_svd(a.as_ref(), 1e-15).unwrap();
        assert_eq!(svd.s.len(), 1);
        assert!(svd.s[0] > 0.0);
        let zero = Mat::<f64>::zeros(5, 5);
        assert_eq!(truncated_svd(zero.as_ref(), 0.01).unwrap().s.len(), 0);
    }

    /// The singular-value-only rank is the decomposition's, over spectra from steep to flat
    /// (the exact gather's noise-like blocks are the flat end) and at several tolerances.
    #[test]
    fn energy_rank_is_the_truncated_svds_rank() {
        let (m, n) = (50, 36);
        let q1 = orthonormal(m, n, 3);
        let q2 = orthonormal(n, n, 4);
        for (decay, tol) in [
            (0.5, 1e-4),
            (0.8, 1e-3),
            (0.95, 1e-3),
            (0.99, 1e-2),
            (1.0, 1e-3),
        ] {
            let sigma: Vec<f64> = (0..n).map(|i| f64::powi(decay, i as i32)).collect();
            let a = with_spectrum(&q1, &sigma, &q2);
            let k = truncated_svd(a.as_ref(), tol).unwrap().s.len();
            assert_eq!(energy_rank(a.as_ref(), tol).unwrap(), k, "decay {decay}");
            assert_eq!(k, rank_for_energy(&sigma, tol), "decay {decay}");
        }
        let zero = Mat::<f64>::zeros(4, 3);
        assert_eq!(energy_rank(zero.as_ref(), 1e-3).unwrap(), 0);
        let mut nan = Mat::<f64>::zeros(4, 3);
        nan[(2, 1)] = f64::NAN;
        assert!(matches!(
            energy_rank(nan.as_ref(), 1e-3),
            Err(LowRankError::NonFinite)
        ));
    }

    /// Above [`GRAM_MIN_SIDE`] the rank comes from the Gram matrix's eigenvalues: the same rank
    /// as the decomposition's, tall and wide, dense (known spectra) and mostly zeros (the exact
    /// gather's ray-hit fractions, where the Gram matrix is summed over nonzeros).
    #[test]
    fn energy_rank_from_the_gram_matrix_is_the_decompositions() {
        let (m, n) = (150, 90);
        let q1 = orthonormal(m, n, 5);
        let q2 = orthonormal(n, n, 6);
        for (decay, tol) in [(0.5, 1e-4), (0.9, 1e-3), (0.97, 1e-3), (1.0, 1e-2)] {
            let sigma: Vec<f64> = (0..n).map(|i| f64::powi(decay, i as i32)).collect();
            let a = with_spectrum(&q1, &sigma, &q2);
            let k = truncated_svd(a.as_ref(), tol).unwrap().s.len();
            assert_eq!(k, rank_for_energy(&sigma, tol), "decay {decay}");
            assert_eq!(energy_rank(a.as_ref(), tol).unwrap(), k, "decay {decay}");
            let wide = a.transpose().to_owned();
            assert_eq!(energy_rank(wide.as_ref(), tol).unwrap(), k, "decay {decay}");
        }
        // Hit fractions: ~6% nonzero, a few hits of 1/1024 each, plus one strong column.
        let hits = hit_fractions((300, 120), 77, 16, 0.004);
        for tol in [1e-1, 1e-2, 1e-3] {
            let s = hits.singular_values().unwrap();
            let k = energy_rank(hits.as_ref(), tol).unwrap();
            assert_eq!(k, rank_for_energy(&s, tol), "tolerance {tol}");
            assert!(k > 1 && k < 120, "rank {k}");
        }
    }

    /// The partial-spectrum proof never claims a rank it does not have: over spectra decaying
    /// fast, slowly and not at all, tall and wide, and every bound `m` below the short side,
    /// `rank_surely_exceeds(a, τ, m)` implies `energy_rank(a, τ) > m`. And it proves what it
    /// is for: a noise-like hit-fraction matrix with one strong column (the exact gather's
    /// ranges) is refused at bounds up to half its rank, a rank-5 matrix is never claimed above
    /// 5, and a non-finite entry is the same error as `energy_rank`'s.
    #[test]
    fn a_proven_rank_bound_is_never_wrong_and_proves_noise() {
        let (m, n) = (220, 140);
        let q1 = orthonormal(m, n, 11);
        let q2 = orthonormal(n, n, 12);
        let mut proven = 0;
        for (decay, tol) in [(0.5, 1e-4), (0.9, 1e-3), (0.97, 1e-5), (1.0, 1e-2)] {
            let sigma: Vec<f64> = (0..n).map(|i| f64::powi(decay, i as i32)).collect();
            let tall = with_spectrum(&q1, &sigma, &q2);
            let k = rank_for_energy(&sigma, tol);
            for a in [tall.clone(), tall.transpose().to_owned()] {
                assert_eq!(energy_rank(a.as_ref(), tol).unwrap(), k, "decay {decay}");
                for bound in 0..n {
                    if rank_surely_exceeds(a.as_ref(), tol, bound).unwrap() {
                        assert!(k > bound, "decay {decay}: rank {k} claimed above {bound}");
                        proven += 1;
                    }
                }
            }
        }
        assert!(proven > 100, "only {proven} bounds proven");
        let hits = hit_fractions((600, 256), 91, 5, 0.02);
        let tol = 1e-5;
        let k = energy_rank(hits.as_ref(), tol).unwrap();
        assert!(k > 200, "rank {k}");
        for bound in [0, 10, 50, k / 2] {
            assert!(
                rank_surely_exceeds(hits.as_ref(), tol, bound).unwrap(),
                "bound {bound}"
            );
        }
        assert!(!rank_surely_exceeds(hits.as_ref(), tol, k).unwrap());
        let sigma: Vec<f64> = (0..n).map(|i| if i < 5 { 1.0 } else { 0.0 }).collect();
        let five = with_spectrum(&q1, &sigma, &q2);
        for bound in 5..n {
            assert!(!rank_surely_exceeds(five.as_ref(), 1e-6, bound).unwrap());
        }
        let mut bad = five.clone();
        bad[(3, 4)] = f64::NAN;
        assert!(matches!(
            rank_surely_exceeds(bad.as_ref(), 1e-3, 1),
            Err(LowRankError::NonFinite)
        ));
    }

    /// The Gram route's basis is the SVD's: the same rank and dropped energy, orthonormal
    /// columns (to 1e-12), and the same subspace (projectors within 1e-8), tall and wide, for
    /// spectra decaying fast, slowly and not at all.
    #[test]
    fn the_column_basis_is_the_svds_left_vectors() {
        let (m, n) = (160, 96);
        let q1 = orthonormal(m, n, 7);
        let q2 = orthonormal(n, n, 8);
        for (decay, tol) in [(0.5, 1e-6), (0.9, 1e-3), (0.97, 1e-3), (1.0, 1e-2)] {
            let sigma: Vec<f64> = (0..n).map(|i| f64::powi(decay, i as i32)).collect();
            let tall = with_spectrum(&q1, &sigma, &q2);
            for a in [tall.clone(), tall.transpose().to_owned()] {
                let svd = truncated_svd(a.as_ref(), tol).unwrap();
                let (u, dropped) = truncated_column_basis(a.as_ref(), tol).unwrap();
                assert_eq!(u.ncols(), svd.u.ncols(), "decay {decay}");
                assert!(
                    (dropped - svd.dropped_energy).abs() < 1e-12,
                    "decay {decay}"
                );
                let gram = u.transpose() * &u;
                let eye = Mat::<f64>::identity(u.ncols(), u.ncols());
                assert!((&gram - &eye).norm_max() < 1e-12, "decay {decay}");
                let projector = |b: &Mat<f64>| b * b.transpose();
                let gap = (projector(&u) - projector(&svd.u)).norm_max();
                assert!(gap < 1e-8, "decay {decay}: projectors {gap:.1e} apart");
            }
        }
    }

    /// Ray-hit fractions like the exact gather's: one entry in `every` holds 1–3 hits of 1/1024
    /// (seeded), and column 7 adds `strong` everywhere.
    fn hit_fractions((rows, cols): (usize, usize), seed: u64, every: u64, strong: f64) -> Mat<f64> {
        Mat::from_fn(rows, cols, |i, j| {
            let x = crate::bake::math::sampling::mix64((i * cols + j) as u64 + seed);
            let column = if j == 7 { strong } else { 0.0 };
            column
                + if x.is_multiple_of(every) {
                    (1 + x % 3) as f64 / 1024.0
                } else {
                    0.0
                }
        })
    }

    /// `Q1 diag(σ) Q2ᵀ`: a matrix with singular values `sigma`.
    fn with_spectrum(q1: &Mat<f64>, sigma: &[f64], q2: &Mat<f64>) -> Mat<f64> {
        Mat::from_fn(q1.nrows(), q2.nrows(), |i, j| {
            (0..sigma.len())
                .map(|k| q1[(i, k)] * sigma[k] * q2[(j, k)])
                .sum()
        })
    }

    fn orthonormal(m: usize, n: usize, seed: u64) -> Mat<f64> {
        let a = Mat::from_fn(m, n, |i, j| {
            let x = crate::bake::math::sampling::mix64(seed * 1_000_003 + (i * n + j) as u64);
            (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        });
        a.thin_svd().unwrap().U().to_owned()
    }
}
