//! Low-rank DRT operators: each delta entry, and each source range of the exact clutter
//! gather, replaced by a truncated SVD when that is smaller (ours; the paper ships them dense).
//!
//! - A delta entry `ΔU` (rows × r, source block or clutter object) becomes `left · mix` with
//!   `left = U_k Σ_k` (rows × k) and `mix = V_kᵀ` (k × r); the client computes `mix · x` once
//!   (k values per channel) and then `left · (mix · x)`.
//! - The exact clutter gather (sparse rows over the direct light of every texel, `G`) is cut by
//!   source range — each block's texels, each clutter object's texels — into dense
//!   `G_range` (receiving texels × range) and factored the same way, source
//!   `DeltaSource::Direct`. A range whose factors are not smaller than twice its sparse entries
//!   stays in the sparse gather, as do columns in no range.
//!
//! Rows of buried texels stay dense and exact ([`compact_entry_keeping`]): their inpainted
//! deltas cancel MRT's transport there, and a truncated factor would leave a residue.
//!
//! The rank is the smallest keeping `1 − tolerance` of the entry's energy (the scene's
//! tolerance, as every other rank; the gather's ranges at [`GATHER_TOLERANCE_SCALE`] of it), so
//! the dropped part is at most `√tolerance` of the entry in Frobenius norm. A factorisation is kept only when `k (rows + cols)` is at most
//! [`KEEP_FRACTION`] of the dense size: small entries stay exact.
//!
//! Most candidates are refused, the exact gather's ranges above all (ray-hit fractions are
//! noise-like, of high rank): a candidate's singular values alone are computed first
//! ([`energy_rank`]), and the vectors only when that rank could be kept.
//!
//! Invariant: deterministic — each SVD runs sequentially and the candidates factored side by
//! side (rayon) are taken in their fixed order; rows stay ascending; entries of every source
//! come out in the order they went in.

use faer::Mat;
use rayon::prelude::*;

use lightfarm_proto::bundle::{DeltaEntry, DeltaSource, TexelGather};

use crate::bake::cache::factors::{FactorCache, Factors, MIN_VALUES};
use crate::bake::math::low_rank::{energy_rank, rank_surely_exceeds, truncated_svd, LowRankError};
use crate::bake::math::matrix::to_matrix;

/// A factorisation is kept when its values are at most this fraction of the dense entry's.
pub const KEEP_FRACTION: f64 = 0.8;

/// What compaction did, for the bake report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DeltaCompactionStats {
    /// Delta entries factored / kept dense.
    pub factored: usize,
    pub dense: usize,
    /// Values before and after (delta entries).
    pub values_before: usize,
    pub values_after: usize,
    /// Exact gather: sparse entries before, dense factor values after, sparse entries left.
    pub gather_sparse_before: usize,
    pub gather_factor_values: usize,
    pub gather_sparse_left: usize,
    /// Ranks of the factored entries, in order.
    pub ranks: Vec<usize>,
}

impl DeltaCompactionStats {
    /// Adds `other`'s counts, and its ranks after this one's.
    pub fn merge(&mut self, other: DeltaCompactionStats) {
        self.factored += other.factored;
        self.dense += other.dense;
        self.values_before += other.values_before;
        self.values_after += other.values_after;
        self.gather_sparse_before += other.gather_sparse_before;
        self.gather_factor_values += other.gather_factor_values;
        self.gather_sparse_left += other.gather_sparse_left;
        self.ranks.extend(other.ranks);
    }
}

/// The factors `(left, mix)` of `m` when they are smaller than [`KEEP_FRACTION`] of it and hold
/// at most `max_values` values; from
/// `cache` when it holds this matrix's outcome (the same bits), stored there otherwise.
fn factor(
    m: &Mat<f64>,
    tolerance: f64,
    max_values: usize,
    cache: Option<&FactorCache>,
) -> Result<Factors, LowRankError> {
    let size = (m.nrows(), m.ncols());
    let key = || FactorCache::key(m, tolerance, max_values);
    factor_lazily(size, key, || m, tolerance, max_values, cache)
}

/// [`factor`] of the `size` matrix `build` makes, looked up in `cache` under `key()` (which
/// names that matrix exactly) first: on a hit the matrix is never built. Matrices smaller than
/// [`MIN_VALUES`] are factored without the cache (nor a key).
fn factor_lazily<M: std::borrow::Borrow<Mat<f64>>>(
    (rows, cols): (usize, usize),
    key: impl FnOnce() -> String,
    build: impl FnOnce() -> M,
    tolerance: f64,
    max_values: usize,
    cache: Option<&FactorCache>,
) -> Result<Factors, LowRankError> {
    let cached = cache
        .filter(|_| rows * cols >= MIN_VALUES)
        .map(|cache| (cache, key()));
    if let Some(hit) = cached.as_ref().and_then(|(cache, key)| cache.get(key)) {
        return Ok(hit);
    }
    let factors = factor_now(build().borrow(), tolerance, max_values)?;
    if let Some((cache, key)) = &cached {
        if let Err(e) = cache.put(key, &factors) {
            // Only a later rebake's time depends on it.
            tracing::warn!(error = %e, "could not store a DRT factorisation in the cache");
        }
    }
    Ok(factors)
}

/// Ranks a factorisation may have above the singular-value-only estimate and still be
/// computed ([`factor_now`]): the estimate and the decomposition's own rank can differ by one
/// where a singular value lies within rounding of the energy threshold.
const PRESCREEN_MARGIN: usize = 2;

fn factor_now(m: &Mat<f64>, tolerance: f64, max_values: usize) -> Result<Factors, LowRankError> {
    let (rows, cols) = (m.nrows(), m.ncols());
    if rows.min(cols) <= 2 {
        return Ok(None);
    }
    let too_big = |k: usize| {
        (k * (rows + cols)) as f64 > KEEP_FRACTION * (rows * cols) as f64
            || k * (rows + cols) > max_values
    };
    // Most candidates are refused (the exact gather's ray-hit fractions are noise-like, of
    // high rank), without forming the vectors: refused when the rank is above the largest size
    // kept plus the margin, which part of the spectrum proves for most, and the singular values
    // alone tell for the rest.
    let largest_kept = (0..=rows.min(cols))
        .take_while(|&k| !too_big(k))
        .last()
        .unwrap_or(0);
    let limit = largest_kept + PRESCREEN_MARGIN;
    if rank_surely_exceeds(m.as_ref(), tolerance, limit)?
        || energy_rank(m.as_ref(), tolerance)? > limit
    {
        return Ok(None);
    }
    let svd = truncated_svd(m.as_ref(), tolerance)?;
    let k = svd.s.len();
    if too_big(k) {
        return Ok(None);
    }
    let left = Mat::from_fn(rows, k, |i, j| svd.u[(i, j)] * svd.s[j]);
    let mix = Mat::from_fn(k, cols, |i, j| svd.v[(j, i)]);
    Ok(Some((left, mix)))
}

/// One delta entry, factored when that is smaller.
pub fn compact_entry(
    rows: Vec<u32>,
    source: DeltaSource,
    m: &Mat<f64>,
    tolerance: f64,
    cache: Option<&FactorCache>,
    stats: &mut DeltaCompactionStats,
) -> Result<DeltaEntry, LowRankError> {
    stats.values_before += m.nrows() * m.ncols();
    Ok(match factor(m, tolerance, usize::MAX, cache)? {
        Some((left, mix)) => {
            stats.factored += 1;
            stats.ranks.push(mix.nrows());
            stats.values_after += left.nrows() * left.ncols() + mix.nrows() * mix.ncols();
            DeltaEntry {
                rows,
                source,
                matrix: to_matrix(&left),
                mix: Some(to_matrix(&mix)),
            }
        }
        None => {
            stats.dense += 1;
            stats.values_after += m.nrows() * m.ncols();
            DeltaEntry {
                rows,
                source,
                matrix: to_matrix(m),
                mix: None,
            }
        }
    })
}

/// Like [`compact_entry`], but rows in `exact_rows` (ascending; the buried texels, whose
/// inpainted deltas must cancel MRT exactly) stay in a dense entry of their own.
pub fn compact_entry_keeping(
    rows: &[u32],
    source: DeltaSource,
    m: &Mat<f64>,
    exact_rows: &[u32],
    tolerance: f64,
    cache: Option<&FactorCache>,
    stats: &mut DeltaCompactionStats,
) -> Result<Vec<DeltaEntry>, LowRankError> {
    let (keep, factor_rows): (Vec<usize>, Vec<usize>) =
        (0..rows.len()).partition(|&i| exact_rows.binary_search(&rows[i]).is_ok());
    let pick = |idx: &[usize]| {
        (
            idx.iter().map(|&i| rows[i]).collect::<Vec<u32>>(),
            Mat::from_fn(idx.len(), m.ncols(), |r, c| m[(idx[r], c)]),
        )
    };
    let mut out = Vec::new();
    if !factor_rows.is_empty() {
        let (r, sub) = pick(&factor_rows);
        out.push(compact_entry(r, source, &sub, tolerance, cache, stats)?);
    }
    if !keep.is_empty() {
        let (r, sub) = pick(&keep);
        stats.dense += 1;
        stats.values_before += sub.nrows() * sub.ncols();
        stats.values_after += sub.nrows() * sub.ncols();
        out.push(DeltaEntry {
            rows: r,
            source,
            matrix: to_matrix(&sub),
            mix: None,
        });
    }
    Ok(out)
}

/// The exact gather's ranges are factored to this fraction of the scene's tolerance: the gather
/// multiplies direct light, sharp where a light is near, so a truncation that keeps `1 −
/// tolerance` of a range's energy can move the light a clutter texel gathers by far more than
/// `√tolerance` (maze at 4,096 rays, one light set: the pillars' one-bounce light 7.2% off the
/// dense operator's with the scene's 1e-3, 0.8% at this scale, where no range factors). The delta entries multiply coefficients, smooth
/// by construction, and keep the scene's tolerance.
pub const GATHER_TOLERANCE_SCALE: f64 = 1e-2;

/// How a gather range's cache key describes it ([`FactorCache::key_described`]).
const GATHER_KEY_TAG: &str = "gather range nonzeros (row, column, f32 bits)";

/// Cuts the exact gather by `ranges` (`(first, count)` texel ranges, disjoint) into low-rank
/// entries with `DeltaSource::Direct` sources, each range factored at
/// [`GATHER_TOLERANCE_SCALE`] × `tolerance` (the scene's); returns them and what stays sparse
/// (None when nothing does).
pub fn compact_gather(
    gather: &TexelGather,
    ranges: &[(u32, u32)],
    tolerance: f64,
    cache: Option<&FactorCache>,
    stats: &mut DeltaCompactionStats,
) -> Result<(Vec<DeltaEntry>, Option<TexelGather>), LowRankError> {
    stats.gather_sparse_before += gather.values.len();
    // Which range each column falls in (the first that holds it), by column: one pass over the
    // gather then finds every range's rows, where a scan per range was ranges × entries
    // (1,066 × 5.8 M at 1,000 blocks).
    let end = ranges
        .iter()
        .map(|&(first, count)| first as usize + count as usize)
        .chain(gather.cols.iter().map(|&c| c as usize + 1))
        .max()
        .unwrap_or(0);
    let mut range_at = vec![u32::MAX; end];
    for (ri, &(first, count)) in ranges.iter().enumerate().rev() {
        range_at[first as usize..first as usize + count as usize].fill(ri as u32);
    }
    let range_of =
        |col: u32| Some(range_at[col as usize] as usize).filter(|&r| r != u32::MAX as usize);
    let row_entries = |i: usize| {
        let (s, e) = (
            gather.row_start[i] as usize,
            gather.row_start[i + 1] as usize,
        );
        gather.cols[s..e].iter().zip(&gather.values[s..e])
    };
    // Per range, the gather rows with a column in it (ascending) and its nonzeros.
    let mut rows_of: Vec<Vec<(usize, u32)>> = vec![Vec::new(); ranges.len()];
    let mut nnz_of = vec![0usize; ranges.len()];
    for (i, &row) in gather.rows.iter().enumerate() {
        for (&c, _) in row_entries(i) {
            if let Some(ri) = range_of(c) {
                nnz_of[ri] += 1;
                if rows_of[ri].last().is_none_or(|&(last, _)| last != i) {
                    rows_of[ri].push((i, row));
                }
            }
        }
    }
    // Which ranges become entries: each range's dense block is built and factored on a worker
    // of its own (a worker holds one block at a time), the outcomes taken in range order. A
    // range is kept when its factors hold at most twice its sparse entries. A range's cache key
    // is its nonzeros in the order they are summed (the dense block follows from them), so a
    // cached outcome costs neither the block nor a hash of all of its values.
    let gather_tolerance = GATHER_TOLERANCE_SCALE * tolerance;
    let outcomes: Vec<Factors> = (0..ranges.len())
        .into_par_iter()
        .map(|ri| {
            let (first, count) = ranges[ri];
            let rows = &rows_of[ri];
            if rows.is_empty() {
                return Ok(None);
            }
            let in_range = |i: usize| {
                row_entries(i)
                    .filter(move |(&c, _)| range_of(c) == Some(ri))
                    .map(move |(&c, &v)| ((c - first) as usize, v))
            };
            let size = (rows.len(), count as usize);
            let max_values = 2 * nnz_of[ri];
            let key = || {
                let describe = |h: &mut blake3::Hasher| {
                    // (row, column, value bits) per nonzero, a row's worth per update.
                    let mut bytes = Vec::new();
                    for (r, &(i, _)) in rows.iter().enumerate() {
                        bytes.clear();
                        for (c, v) in in_range(i) {
                            bytes.extend_from_slice(&(r as u32).to_le_bytes());
                            bytes.extend_from_slice(&(c as u32).to_le_bytes());
                            bytes.extend_from_slice(&v.to_bits().to_le_bytes());
                        }
                        h.update(&bytes);
                    }
                };
                FactorCache::key_described(
                    GATHER_KEY_TAG,
                    gather_tolerance,
                    max_values,
                    size,
                    describe,
                )
            };
            let build = || {
                let mut dense = Mat::<f64>::zeros(size.0, size.1);
                for (r, &(i, _)) in rows.iter().enumerate() {
                    for (c, v) in in_range(i) {
                        dense[(r, c)] += v as f64;
                    }
                }
                dense
            };
            factor_lazily(size, key, build, gather_tolerance, max_values, cache)
        })
        .collect::<Result<_, LowRankError>>()?;
    let mut factored_ranges = vec![false; ranges.len()];
    let mut entries = Vec::new();
    for (ri, outcome) in outcomes.into_iter().enumerate() {
        let Some((left, mix)) = outcome else {
            continue;
        };
        let (first, count) = ranges[ri];
        let values = left.nrows() * left.ncols() + mix.nrows() * mix.ncols();
        factored_ranges[ri] = true;
        stats.gather_factor_values += values;
        stats.ranks.push(mix.nrows());
        entries.push(DeltaEntry {
            rows: rows_of[ri].iter().map(|&(_, row)| row).collect(),
            source: DeltaSource::Direct { first, count },
            matrix: to_matrix(&left),
            mix: Some(to_matrix(&mix)),
        });
    }
    // What stays sparse: columns of ranges not factored, and columns in no range.
    let stays = |c: u32| range_of(c).is_none_or(|ri| !factored_ranges[ri]);
    let mut rest = TexelGather {
        tiles: gather.tiles.clone(),
        ..TexelGather::default()
    };
    rest.row_start.push(0);
    // Sized first, not grown entry by entry (the whole gather when no range factors, as on the
    // maze).
    let left = gather.cols.iter().filter(|&&c| stays(c)).count();
    rest.cols.reserve_exact(left);
    rest.values.reserve_exact(left);
    for (i, &row) in gather.rows.iter().enumerate() {
        let before = rest.cols.len();
        for (&c, &v) in row_entries(i) {
            if stays(c) {
                rest.cols.push(c);
                rest.values.push(v);
            }
        }
        if rest.cols.len() > before {
            rest.rows.push(row);
            rest.row_start.push(rest.cols.len() as u32);
        }
    }
    stats.gather_sparse_left += rest.values.len();
    Ok((entries, (!rest.rows.is_empty()).then_some(rest)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rank-2 entry plus a little noise factors to rank ≥ 2, and the product stays within
    /// √tolerance of the entry in Frobenius norm.
    #[test]
    fn low_rank_entry_is_factored_within_the_tolerance() {
        let (rows, cols) = (60, 40);
        let m = Mat::from_fn(rows, cols, |i, j| {
            let (x, y) = (i as f64 / rows as f64, j as f64 / cols as f64);
            (x * 3.0).sin() * (y * 2.0).cos()
                + 0.5 * x * y
                + 1e-3 * (((i * 31 + j * 17) % 13) as f64 - 6.0)
        });
        let mut stats = DeltaCompactionStats::default();
        let e = compact_entry(
            (0..rows as u32).collect(),
            DeltaSource::Block(0),
            &m,
            0.01,
            None,
            &mut stats,
        )
        .unwrap();
        let mix = e.mix.as_ref().expect("factored");
        let k = mix.rows as usize;
        assert!((2..=6).contains(&k), "rank {k}");
        let (mut err, mut norm) = (0.0, 0.0);
        for i in 0..rows {
            for j in 0..cols {
                let v: f64 = (0..k)
                    .map(|l| e.matrix.data[i * k + l] as f64 * mix.data[l * cols + j] as f64)
                    .sum();
                err += (v - m[(i, j)]).powi(2);
                norm += m[(i, j)].powi(2);
            }
        }
        assert!(
            (err / norm).sqrt() <= 0.1 + 1e-6,
            "relative error {}",
            (err / norm).sqrt()
        );
        assert_eq!(stats.factored, 1);
        assert!(stats.values_after < stats.values_before / 2);
    }

    /// Rows named exact are split into a dense entry with their values untouched.
    #[test]
    fn exact_rows_stay_dense() {
        let m = Mat::from_fn(40, 30, |i, j| {
            ((i + 1) * (j + 2)) as f64 * 1e-3 + if i == 5 { 0.3 } else { 0.0 }
        });
        let rows: Vec<u32> = (100..140).collect();
        let mut stats = DeltaCompactionStats::default();
        let out = compact_entry_keeping(
            &rows,
            DeltaSource::Block(2),
            &m,
            &[105, 999],
            0.01,
            None,
            &mut stats,
        )
        .unwrap();
        assert_eq!(out.len(), 2);
        assert!(out[0].mix.is_some() && !out[0].rows.contains(&105));
        assert_eq!(out[1].rows, vec![105]);
        assert!(out[1].mix.is_none());
        assert_eq!(out[1].matrix.data[3], m[(5, 3)] as f32);
    }

    /// A full-rank (identity-like) entry stays dense and exact.
    #[test]
    fn full_rank_entry_stays_dense() {
        let m = Mat::from_fn(10, 10, |i, j| if i == j { 1.0 + i as f64 } else { 0.0 });
        let mut stats = DeltaCompactionStats::default();
        let e = compact_entry(
            (0..10).collect(),
            DeltaSource::Clutter(1),
            &m,
            0.01,
            None,
            &mut stats,
        )
        .unwrap();
        assert!(e.mix.is_none());
        assert_eq!(e.matrix.data[11], 2.0);
        assert_eq!(stats.dense, 1);
    }

    /// A gather whose rows over one range are rank one is factored for that range; columns
    /// outside every range and a range too sparse to pay stay sparse, values untouched.
    #[test]
    fn gather_is_cut_by_range() {
        // Rows 100..130 read texels 0..20 with weights a_i · b_j (rank one), texel 50 (in no
        // range) and one texel of range (30, 10) each (full rank and sparse: not worth factoring).
        let mut g = TexelGather::default();
        g.row_start.push(0);
        for i in 0..30u32 {
            g.rows.push(100 + i);
            for j in 0..20u32 {
                g.cols.push(j);
                g.values
                    .push((1.0 + i as f32) * (1.0 + (j % 5) as f32) * 1e-3);
            }
            // One texel of range (30, 10) per row, a different one each row: rank 10.
            g.cols.push(30 + i % 10);
            g.values.push(0.5 + i as f32);
            g.cols.push(50);
            g.values.push(0.25);
            g.row_start.push(g.cols.len() as u32);
        }
        let mut stats = DeltaCompactionStats::default();
        let (entries, rest) =
            compact_gather(&g, &[(0, 20), (30, 10)], 1e-4, None, &mut stats).unwrap();
        assert_eq!(entries.len(), 1);
        let e = &entries[0];
        assert_eq!(
            e.source,
            DeltaSource::Direct {
                first: 0,
                count: 20
            }
        );
        assert_eq!(e.rows, (100..130).collect::<Vec<_>>());
        let mix = e.mix.as_ref().unwrap();
        assert_eq!(mix.rows, 1);
        // Row 7, column 3 reproduced.
        let v = e.matrix.data[7] * mix.data[3];
        assert!((v - 8.0 * 4.0 * 1e-3).abs() < 1e-6);
        let rest = rest.unwrap();
        assert_eq!(rest.rows.len(), 30);
        assert_eq!(rest.cols[..2], [30, 50]);
        assert_eq!(rest.values[..2], [0.5, 0.25]);
        assert_eq!(stats.gather_sparse_left, 60);
    }

    /// Why the bundle factors the gather at a fraction of the scene's tolerance
    /// (`GATHER_TOLERANCE_SCALE`): the gather multiplies direct light, bright where a light is
    /// near. A range whose rows see a smooth floor plus a small patch of it lit differently
    /// (its second component holds 3e-4 of the energy) loses the patch at the scene's 1e-3, and
    /// with it most of the light gathered from a lamp over the patch; at the bundle's scale it
    /// keeps it.
    #[test]
    fn a_point_lights_gather_survives_the_bundles_gather_tolerance() {
        let (rows, cols) = (100usize, 200usize);
        let patch = 60..64;
        let a = |i: usize| 1.0 + i as f64 / rows as f64;
        let b = |j: usize| 0.01 * (1.5 + (j as f64 * 0.1).sin());
        let d = |i: usize| 1.0 + (i % 7) as f64;
        // Scale of the patch's component: 3e-4 of the smooth part's energy.
        let smooth: f64 = (0..rows)
            .flat_map(|i| (0..cols).map(move |j| (a(i) * b(j)).powi(2)))
            .sum();
        let detail: f64 = (0..rows).map(|i| d(i).powi(2) * patch.len() as f64).sum();
        let c = (3e-4 * smooth / detail).sqrt();
        let value =
            |i: usize, j: usize| a(i) * b(j) + if patch.contains(&j) { c * d(i) } else { 0.0 };
        let mut g = TexelGather::default();
        g.row_start.push(0);
        for i in 0..rows {
            g.rows.push(1000 + i as u32);
            for j in 0..cols {
                g.cols.push(j as u32);
                g.values.push(value(i, j) as f32);
            }
            g.row_start.push(g.cols.len() as u32);
        }
        // Direct light: a lamp over the patch on a dim floor.
        let x: Vec<f64> = (0..cols)
            .map(|j| if patch.contains(&j) { 100.0 } else { 1.0 })
            .collect();
        let exact: Vec<f64> = (0..rows)
            .map(|i| (0..cols).map(|j| value(i, j) * x[j]).sum())
            .collect();
        let error_at = |tolerance: f64| {
            let mut stats = DeltaCompactionStats::default();
            let (entries, _) =
                compact_gather(&g, &[(0, cols as u32)], tolerance, None, &mut stats).unwrap();
            let e = &entries[0];
            let mix = e.mix.as_ref().unwrap();
            let k = mix.rows as usize;
            let y: Vec<f64> = (0..k)
                .map(|q| {
                    (0..cols)
                        .map(|j| mix.data[q * cols + j] as f64 * x[j])
                        .sum()
                })
                .collect();
            let (mut num, mut den) = (0.0, 0.0);
            for (r, want) in exact.iter().enumerate() {
                let got: f64 = (0..k).map(|q| e.matrix.data[r * k + q] as f64 * y[q]).sum();
                num += (got - want).powi(2);
                den += want.powi(2);
            }
            ((num / den).sqrt(), k)
        };
        // The scene's 1e-3 unscaled, and as `compact_gather` scales it.
        let (scene, bundle) = (error_at(1e-3 / GATHER_TOLERANCE_SCALE), error_at(1e-3));
        assert_eq!((scene.1, bundle.1), (1, 2), "ranks");
        assert!(
            bundle.0 <= 1e-4,
            "at the bundle's gather tolerance: {}",
            bundle.0
        );
        // 4.2%: the patch's light, a small share of the gather's energy, a large one of a
        // lamp's.
        assert!(scene.0 >= 0.03, "at the scene's: {}", scene.0);
    }
}
