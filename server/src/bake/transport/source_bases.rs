//! Shared source bases for compact transport (ours; bundle transport kind 3): the second side
//! of the compaction. [`super::compaction`] gives each receiving block B one low-rank operator
//! `Y_B Z_B` over the stacked coefficients of its sources; `Z_B` (k_B × Σ r_A) is most of a large
//! level's bytes, one column per source shape coefficient. But what B receives from a source
//! A passes A's openings, so across every receiver the rows `Y_B Z_BA` span few directions of
//! A's coefficient space: the truncated SVD of the stacked `[Y_B Z_BA]_B` gives a row basis
//! `Q_A` (j_A × r_A, orthonormal rows) shared by all of A's receivers, and each receiver keeps
//! `Z'_BA = Z_BA Q_Aᵀ` (k_B × j_A): `Y_B Z_BA ≈ Y_B Z'_BA Q_A`.
//!
//! Because `Y_B = U_k Σ_k` has orthogonal columns, `‖Y_B Z_BA x‖ = ‖Σ_k Z_BA x‖`, so the SVD runs
//! on `[diag(‖y_B,i‖) Z_BA]_B` (Σ k_B × r_A) rather than on texels. j_A comes from the scene's
//! tolerance as every rank does (dropped energy of that stack ≤ tolerance), so each receiver
//! loses about the share of A's light the target side already may. A source is factored only
//! when `Q_A` and the `Z'_BA` hold fewer values than the `Z_BA` they replace.
//!
//! Units: `Z'` as `Z` (albedo-free radiance per unit of b, scaled by `Y`); `Q` dimensionless.
//!
//! Invariant: sources are factored in parallel but each SVD and product is sequential and
//! results are collected in block order, so the bits do not depend on the thread count; a
//! pure function of the f32 compaction, so a cached compaction factors to the same bundle.

use faer::Mat;
use rayon::prelude::*;

use lightfarm_proto::bundle::{CompactEntry, SourceBases, SourceBasis};

use crate::bake::math::low_rank::{truncated_svd, LowRankError};
use crate::bake::math::matrix::{from_matrix, to_matrix};

/// What factoring did, for the bake report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FactoringStats {
    /// Sources with a basis, and their ranks j (ascending block order).
    pub basis_ranks: Vec<usize>,
    /// Sources read by some receiver.
    pub sources: usize,
    /// Values of every `Z` before, and of every `Z'` plus every `Q` after.
    pub values_before: usize,
    pub values_after: usize,
}

/// Where source `a`'s columns sit in each receiver's `Z`: (entry index, first column).
fn columns_by_source(entries: &[CompactEntry], rank: &[usize]) -> Vec<Vec<(usize, usize)>> {
    let mut by_source = vec![Vec::new(); rank.len()];
    for (i, e) in entries.iter().enumerate() {
        let mut at = 0;
        for &s in &e.sources {
            by_source[s as usize].push((i, at));
            at += rank[s as usize];
        }
    }
    by_source
}

/// Column norms of each entry's `Y` (they weigh the rows of its `Z`; the columns are
/// orthogonal), once per entry for every source it reads.
fn y_column_norms(entries: &[CompactEntry]) -> Vec<Vec<f64>> {
    entries
        .par_iter()
        .map(|e| {
            let k = e.y.cols as usize;
            (0..k)
                .map(|c| {
                    (0..e.y.rows as usize)
                        .map(|t| f64::from(e.y.data[t * k + c]).powi(2))
                        .sum::<f64>()
                        .sqrt()
                })
                .collect()
        })
        .collect()
}

/// Source `a`'s row basis `Q_a` (j × r), or None when factoring it saves nothing.
fn source_basis(
    entries: &[CompactEntry],
    y_norms: &[Vec<f64>],
    columns: &[(usize, usize)],
    r: usize,
    tolerance: f64,
) -> Result<Option<Mat<f64>>, LowRankError> {
    let rows: usize = columns
        .iter()
        .map(|&(i, _)| entries[i].z.rows as usize)
        .sum();
    if rows == 0 || r == 0 {
        return Ok(None);
    }
    let mut stack = Mat::<f64>::zeros(rows, r);
    let mut row = 0;
    for &(i, at) in columns {
        let e = &entries[i];
        for (c, &norm) in y_norms[i].iter().enumerate() {
            let z = e.z.row(c);
            for j in 0..r {
                stack[(row, j)] = norm * f64::from(z[at + j]);
            }
            row += 1;
        }
    }
    let svd = truncated_svd(stack.as_ref(), tolerance)?;
    let j = svd.s.len().max(1);
    if j * (r + rows) >= r * rows {
        return Ok(None);
    }
    Ok(Some(Mat::from_fn(j, r, |m, c| {
        if m < svd.v.ncols() {
            svd.v[(c, m)]
        } else {
            0.0
        }
    })))
}

/// Factors `entries` (plain compact transport, `z` over every source's `rank` columns) into
/// shared source bases at `tolerance`. With no source worth factoring, the entries come back
/// unchanged and `bases` empty.
pub fn factor_sources(
    entries: Vec<CompactEntry>,
    rank: &[usize],
    tolerance: f64,
) -> Result<(SourceBases, FactoringStats), LowRankError> {
    let by_source = columns_by_source(&entries, rank);
    let y_norms = y_column_norms(&entries);
    let bases: Vec<Option<Mat<f64>>> = by_source
        .par_iter()
        .enumerate()
        .map(|(a, cols)| source_basis(&entries, &y_norms, cols, rank[a], tolerance))
        .collect::<Result<_, _>>()?;
    let values_before = entries.iter().map(|e| e.z.data.len()).sum();
    let entries: Vec<CompactEntry> = entries
        .into_par_iter()
        .map(|e| {
            if e.sources.iter().all(|&s| bases[s as usize].is_none()) {
                return e;
            }
            let z = from_matrix(&e.z);
            let k = z.nrows();
            let width: usize = e
                .sources
                .iter()
                .map(|&s| {
                    bases[s as usize]
                        .as_ref()
                        .map_or(rank[s as usize], |q| q.nrows())
                })
                .sum();
            let mut out = Mat::<f64>::zeros(k, width);
            let (mut from, mut to) = (0, 0);
            for &s in &e.sources {
                let r = rank[s as usize];
                match &bases[s as usize] {
                    Some(q) => {
                        let j = q.nrows();
                        // Z'_BA = Z_BA Q_Aᵀ, summed in column order.
                        for i in 0..k {
                            for m in 0..j {
                                let mut sum = 0.0;
                                for c in 0..r {
                                    sum += z[(i, from + c)] * q[(m, c)];
                                }
                                out[(i, to + m)] = sum;
                            }
                        }
                        to += j;
                    }
                    None => {
                        out.subcols_mut(to, r).copy_from(z.subcols(from, r));
                        to += r;
                    }
                }
                from += r;
            }
            CompactEntry {
                z: to_matrix(&out),
                ..e
            }
        })
        .collect();
    let bases: Vec<SourceBasis> = bases
        .iter()
        .enumerate()
        .filter_map(|(a, q)| {
            q.as_ref().map(|q| SourceBasis {
                source_block: a as u32,
                q: to_matrix(q),
            })
        })
        .collect();
    let stats = FactoringStats {
        basis_ranks: bases.iter().map(|b| b.q.rows as usize).collect(),
        sources: by_source.iter().filter(|c| !c.is_empty()).count(),
        values_before,
        values_after: entries.iter().map(|e| e.z.data.len()).sum::<usize>()
            + bases.iter().map(|b| b.q.data.len()).sum::<usize>(),
    };
    Ok((SourceBases { bases, entries }, stats))
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::bundle::Matrix;
    use lightfarm_proto::testing::Lcg;

    fn random(rng: &mut Lcg, rows: usize, cols: usize) -> Mat<f64> {
        Mat::from_fn(rows, cols, |_, _| f64::from(rng.unit()) - 0.5)
    }

    /// The product `a · b` of two bundle matrices, in f64.
    fn product(a: &Matrix, b: &Matrix) -> Mat<f64> {
        from_matrix(a) * from_matrix(b)
    }

    /// Receivers 0 and 1 read sources 1, 2 and 0, 2; source 2's light lies in a rank-2 row
    /// space for both, source 0's and 1's is full rank.
    fn level() -> (Vec<CompactEntry>, Vec<usize>) {
        let mut rng = Lcg(7);
        let rank = vec![3, 4, 12];
        let shared = random(&mut rng, 2, 12);
        let entry = |rng: &mut Lcg, target: u32, sources: Vec<u32>| {
            let k = 5;
            // Orthogonal columns (Gram–Schmidt), as the compaction's Y = U Σ, scaled k − i.
            let mut y = random(rng, 20, k);
            for i in 0..k {
                for p in 0..i {
                    let d: f64 = (0..20).map(|t| y[(t, i)] * y[(t, p)]).sum();
                    let n: f64 = (0..20).map(|t| y[(t, p)] * y[(t, p)]).sum();
                    for t in 0..20 {
                        y[(t, i)] -= d / n * y[(t, p)];
                    }
                }
                let n = (0..20).map(|t| y[(t, i)].powi(2)).sum::<f64>().sqrt();
                for t in 0..20 {
                    y[(t, i)] *= (k - i) as f64 / n;
                }
            }
            let blocks: Vec<Mat<f64>> = sources
                .iter()
                .map(|&s| match s {
                    2 => random(rng, k, 2) * &shared,
                    s => random(rng, k, rank[s as usize]),
                })
                .collect();
            let width = blocks.iter().map(|b| b.ncols()).sum();
            let mut z = Mat::<f64>::zeros(k, width);
            let mut at = 0;
            for b in &blocks {
                z.subcols_mut(at, b.ncols()).copy_from(b);
                at += b.ncols();
            }
            CompactEntry {
                target_block: target,
                sources,
                y: to_matrix(&y),
                z: to_matrix(&z),
            }
        };
        let entries = vec![
            entry(&mut rng, 0, vec![1, 2]),
            entry(&mut rng, 1, vec![0, 2]),
        ];
        (entries, rank)
    }

    #[test]
    fn a_low_rank_source_gets_a_basis_that_reproduces_its_light() {
        let (entries, rank) = level();
        let (f, stats) = factor_sources(entries.clone(), &rank, 1e-6).unwrap();
        // Only source 2 is worth factoring: rank 2 of 12 columns.
        assert_eq!(f.bases.len(), 1);
        assert_eq!(f.bases[0].source_block, 2);
        assert_eq!(f.bases[0].q.rows, 2);
        assert_eq!(stats.basis_ranks, vec![2]);
        assert_eq!(stats.sources, 3);
        assert_eq!(stats.values_before, 2 * 5 * 16 + 5 * 15 - 5 * 16);
        assert_eq!(stats.values_after, 5 * (4 + 2) + 5 * (3 + 2) + 2 * 12);
        // Unfolded, every receiver's Y Z is the original to f32 rounding.
        let unfolded = f.unfold(|b| rank[b as usize] as u32);
        for (a, b) in entries.iter().zip(&unfolded) {
            let (want, got) = (product(&a.y, &a.z), product(&b.y, &b.z));
            let err = (&want - &got).norm_l2() / want.norm_l2();
            assert!(
                err < 1e-5,
                "receiver {}: relative error {err}",
                a.target_block
            );
        }
    }

    #[test]
    fn the_dropped_share_of_a_source_follows_the_tolerance() {
        let (entries, rank) = level();
        // Give source 2 a weak third direction (one row, the same at both receivers): 1e-2 of
        // its light, 1e-4 of its energy.
        let mut rng = Lcg(11);
        let direction = random(&mut rng, 1, 12);
        let mut noisy = entries.clone();
        for e in &mut noisy {
            let k = e.z.rows as usize;
            let at = e.z.cols as usize - 12;
            let weak = random(&mut rng, k, 1) * &direction;
            let scale = 1e-2 * from_matrix(&e.z).subcols(at, 12).norm_l2() / weak.norm_l2();
            for i in 0..k {
                for c in 0..12 {
                    e.z.data[i * e.z.cols as usize + at + c] += (scale * weak[(i, c)]) as f32;
                }
            }
        }
        let (tight, _) = factor_sources(noisy.clone(), &rank, 1e-6).unwrap();
        assert_eq!(tight.bases[0].q.rows, 3);
        let (loose, _) = factor_sources(noisy.clone(), &rank, 1e-3).unwrap();
        assert_eq!(loose.bases[0].q.rows, 2);
        let unfolded = loose.unfold(|b| rank[b as usize] as u32);
        for (a, b) in noisy.iter().zip(&unfolded) {
            let (want, got) = (product(&a.y, &a.z), product(&b.y, &b.z));
            let err = (&want - &got).norm_l2() / want.norm_l2();
            // Source 2's dropped 1% of its light, diluted by the receiver's other source.
            assert!(
                err > 1e-4 && err < 1.5e-2,
                "receiver {}: {err}",
                a.target_block
            );
        }
    }

    #[test]
    fn factoring_is_the_same_bits_at_any_thread_count() {
        let (entries, rank) = level();
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let a = one.install(|| factor_sources(entries.clone(), &rank, 1e-3).unwrap());
        let b = factor_sources(entries, &rank, 1e-3).unwrap();
        assert_eq!(a, b);
    }
}
