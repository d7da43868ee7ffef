//! The per-frame kernels of [`super::Runtime`]: views of channel-planar scratch vectors and the
//! packed matrix-vector products every stage is built from, plus the block loop that runs
//! blocks on one thread or under `rayon::join` with bit-identical results.
//!
//! Layout convention: channel c of a planar n-vector sits at `c·n .. (c+1)·n`; a "group" is a
//! block's or clutter object's `3 × width` values, channel-planar.

use crate::packed::PackedMatrix;

use super::packed_ops::BlockSlots;

/// The three channel slices `[offset, offset + len)` of a planar 3 × `stride` vector.
#[inline]
pub(super) fn planar(v: &[f32], stride: usize, offset: usize, len: usize) -> [&[f32]; 3] {
    [
        &v[offset..offset + len],
        &v[stride + offset..stride + offset + len],
        &v[2 * stride + offset..2 * stride + offset + len],
    ]
}

/// The first `len` values of each channel of a channel-planar group of `3 × width` values
/// starting at `start` (a block's or clutter object's coefficients, an opening's lightfield).
#[inline]
pub(super) fn group(v: &[f32], start: usize, width: usize, len: usize) -> [&[f32]; 3] {
    planar(&v[start..start + 3 * width], width, 0, len)
}

/// Stacks the coefficients of the blocks `sources` (a compact transport entry's), each block's
/// `b` group side by side, into the channel-planar `3 × width` vector `x` (what the entry's `Z`
/// multiplies); a source that `reached` refuses gets zeros.
#[inline]
pub(super) fn stack_sources(
    blocks: &[BlockSlots],
    b: &[f32],
    sources: &[u32],
    width: usize,
    x: &mut [f32],
    reached: impl Fn(u32) -> bool,
) {
    let mut col = 0;
    for &s in sources {
        let src = &blocks[s as usize];
        let r = src.rank;
        for ch in 0..3 {
            let from = src.coef_start + ch * r;
            let to = &mut x[ch * width + col..ch * width + col + r];
            if reached(s) {
                to.copy_from_slice(&b[from..from + r]);
            } else {
                to.fill(0.0);
            }
        }
        col += r;
    }
}

/// `out[t] += M · x` for every row t of `m`.
#[inline]
pub(super) fn add_matvec(
    out: &mut [[f32; 3]],
    m: &PackedMatrix,
    x: [&[f32]; 3],
    scratch: &mut [f32],
) {
    m.matvec(x, scratch, |t, v| {
        let o = &mut out[t];
        o[0] += v[0];
        o[1] += v[1];
        o[2] += v[2];
    });
}

/// `dst[c·width + j] = M.row(j) · x` (channel c) for every row j of `m`, into a channel-planar
/// group of `3 × width` values (`width ≥ m.rows`).
#[inline]
pub(super) fn set_matvec(
    dst: &mut [f32],
    width: usize,
    m: &PackedMatrix,
    x: [&[f32]; 3],
    scratch: &mut [f32],
) {
    let every = 0..m.cols();
    set_matvec_columns(dst, width, m, x, std::slice::from_ref(&every), scratch)
}

/// [`set_matvec`] when `x` is zero outside `columns` ([`PackedMatrix::matvec_columns`]: the
/// same values, reading those columns alone).
#[inline]
pub(super) fn set_matvec_columns(
    dst: &mut [f32],
    width: usize,
    m: &PackedMatrix,
    x: [&[f32]; 3],
    columns: &[std::ops::Range<usize>],
    scratch: &mut [f32],
) {
    m.matvec_columns(x, columns, scratch, |j, v| {
        dst[j] = v[0];
        dst[width + j] = v[1];
        dst[2 * width + j] = v[2];
    });
}

/// `dst[c·width + j] += M.row(j) · x` (channel c), like [`set_matvec`].
#[inline]
pub(super) fn acc_matvec(
    dst: &mut [f32],
    width: usize,
    m: &PackedMatrix,
    x: [&[f32]; 3],
    scratch: &mut [f32],
) {
    m.matvec(x, scratch, |j, v| {
        dst[j] += v[0];
        dst[width + j] += v[1];
        dst[2 * width + j] += v[2];
    });
}

/// `out[rows[i]] += M.row(i) · x` (per channel) for every row i of `m`.
#[inline]
pub(super) fn scatter_matvec(
    out: &mut [[f32; 3]],
    rows: &[u32],
    m: &PackedMatrix,
    x: [&[f32]; 3],
    scratch: &mut [f32],
) {
    m.matvec(x, scratch, |i, v| {
        let o = &mut out[rows[i] as usize];
        o[0] += v[0];
        o[1] += v[1];
        o[2] += v[2];
    });
}

/// Runs `work(k, a_k, b_k)` for every block k in `lo..hi`, where `a_k`/`b_k` are block k's
/// ranges of `a`/`b` (slices that start at global offsets `a_base`/`b_base`; the ranges come
/// from `range_a`/`range_b`, ascending and disjoint). With `parallel`, halves of the block list
/// run under `rayon::join`; each block's work is the same either way, so results are
/// bit-identical at any thread count.
#[allow(clippy::too_many_arguments)]
pub(super) fn for_each_block<A: Send, B: Send, F>(
    lo: usize,
    hi: usize,
    (a, a_base): (&mut [A], usize),
    (b, b_base): (&mut [B], usize),
    range_a: &(impl Fn(usize) -> (usize, usize) + Sync),
    range_b: &(impl Fn(usize) -> (usize, usize) + Sync),
    parallel: bool,
    work: &F,
) where
    F: Fn(usize, &mut [A], &mut [B]) + Sync,
{
    #[cfg(feature = "rayon")]
    if parallel && hi - lo > 1 {
        let mid = (lo + hi) / 2;
        let (a_lo, a_hi) = a.split_at_mut(range_a(mid).0 - a_base);
        let (b_lo, b_hi) = b.split_at_mut(range_b(mid).0 - b_base);
        let a_mid = range_a(mid).0;
        let b_mid = range_b(mid).0;
        rayon::join(
            || {
                for_each_block(
                    lo,
                    mid,
                    (a_lo, a_base),
                    (b_lo, b_base),
                    range_a,
                    range_b,
                    true,
                    work,
                )
            },
            || {
                for_each_block(
                    mid,
                    hi,
                    (a_hi, a_mid),
                    (b_hi, b_mid),
                    range_a,
                    range_b,
                    true,
                    work,
                )
            },
        );
        return;
    }
    let _ = parallel;
    for k in lo..hi {
        let (a0, a1) = range_a(k);
        let (b0, b1) = range_b(k);
        work(
            k,
            &mut a[a0 - a_base..a1 - a_base],
            &mut b[b0 - b_base..b1 - b_base],
        );
    }
}
