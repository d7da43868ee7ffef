//! The lossless prediction of 8-bit q (codec tags 4 and 5): an operator's lines seen as images
//! over the texel grid, the residuals `(q − pred) mod 256` the predicted forms store, and the
//! encoder's choices (predictor width, and predicted or plain) by order-0 entropy.
//!
//! Prediction: the lines of our big operators run along the texel axis (U_b's columns, T_d→b's
//! rows, transport `y`'s columns), where texels come per box face as T × T grids, face after
//! face, and lighting is smooth. A line of n q is read as an image `width` wide (the last image
//! row may be partial): element k sits at (y, x) = (k / width, k % width), its left neighbour is
//! k − 1 if x > 0, its upper one k − width if y > 0, its upper-left one k − width − 1 if both.
//! With both, pred is the LOCO-I / JPEG-LS median of (left, up, left + up − upleft); with one,
//! that one; with none, 0. `width` 0 predicts the previous value on the line (0 for the first).
//! The bundle writer stores an 8-bit matrix predicted when the order-0 entropy of its residuals
//! (best of width 0 and [`PREDICTOR_WIDTHS`]) is below that of the plain q
//! ([`super::write_matrix_smallest`]); with T × T faces the width T wins, and zstd codes the
//! operators in fewer bytes (maze at T = 8: shapes −25%, transport −19%, DRT −9%).
//!
//! Invariant: [`predict`] reads only earlier elements of a line, so undoing the residuals in line
//! order gives back the q exactly, for any width (0, 1, ≥ the line, `u16::MAX`).

use super::MatrixCodec;

/// Of an 8-bit matrix's plain codec `plain` and its predicted form, the smaller by the
/// order-0 entropy estimate (the predicted one only when its residuals, plus the 16 bits of
/// the width, take fewer bits than the plain q), with the predictor width; and the q line by
/// line (what a predicted form stores; a plain one ignores the order).
pub(super) fn u8_form(
    q: &[u8],
    rows: usize,
    cols: usize,
    plain: MatrixCodec,
) -> ((MatrixCodec, u16), Vec<u8>) {
    let mut counts = ByteCounts::default();
    counts.add(q);
    let plain_bits = entropy_bits(&counts.total());
    let lines = to_lines(q, rows, cols, plain.per_column());
    let (width, predicted_bits) = best_predictor_width(&lines, line_len(rows, cols, plain));
    if predicted_bits + 16.0 < plain_bits {
        ((plain.predicted(), width), lines)
    } else {
        ((plain, 0), lines)
    }
}

/// Length of one line (a column for per-column codecs, else a row).
pub(super) fn line_len(rows: usize, cols: usize, codec: MatrixCodec) -> usize {
    if codec.per_column() {
        rows
    } else {
        cols
    }
}

/// Row-major q rearranged so that each line (column or row) is contiguous.
pub(super) fn to_lines(q: &[u8], rows: usize, cols: usize, per_column: bool) -> Vec<u8> {
    if !per_column {
        return q.to_vec();
    }
    let mut out = Vec::with_capacity(q.len());
    for j in 0..cols {
        out.extend((0..rows).map(|i| q[i * cols + j]));
    }
    out
}

/// The prediction of `line[k]` from `line[..k]` with the line seen as an image `width` wide
/// (module doc); `width` 0 predicts the previous value.
#[inline]
pub(super) fn predict(line: &[u8], k: usize, width: usize) -> u8 {
    if width == 0 {
        return if k > 0 { line[k - 1] } else { 0 };
    }
    let has_left = !k.is_multiple_of(width);
    let has_up = k >= width;
    match (has_left, has_up) {
        (false, false) => 0,
        (true, false) => line[k - 1],
        (false, true) => line[k - width],
        (true, true) => median(line[k - 1], line[k - width], line[k - width - 1]),
    }
}

/// The LOCO-I / JPEG-LS median of (left, up, left + up − upleft): always within [min, max]
/// of left and up. Written as `left + up − upleft` clamped to [min, max] of left and up (the
/// same value in every case: above both, it is the smaller; below both, the larger), without
/// branches, so that a row of residuals vectorizes.
#[inline]
fn median(left: u8, up: u8, upleft: u8) -> u8 {
    let (a, b, c) = (left as i16, up as i16, upleft as i16);
    (a + b - c).clamp(a.min(b), a.max(b)) as u8
}

/// `(q − prediction) mod 256` of every value of one line, into `dst` (as long as the line):
/// what [`predict`] gives, walked image row by image row so that no element needs a division
/// or a branch on its position.
pub(super) fn residuals_into(line: &[u8], width: usize, dst: &mut [u8]) {
    let n = line.len();
    assert_eq!(dst.len(), n, "one residual per value");
    if n == 0 {
        return;
    }
    // The first value has no neighbour; the rest of the first image row (all of the line for
    // width 0) predicts from the left.
    dst[0] = line[0];
    let first_row = if width == 0 { n } else { width.min(n) };
    for k in 1..first_row {
        dst[k] = line[k].wrapping_sub(line[k - 1]);
    }
    let mut start = first_row;
    while start < n {
        let end = (start + width).min(n);
        // A row's first value predicts from above, the others by the median.
        dst[start] = line[start].wrapping_sub(line[start - width]);
        let (row, up) = (&line[start..end], &line[start - width..end - width]);
        let out = &mut dst[start..end];
        for i in 1..row.len() {
            out[i] = row[i].wrapping_sub(median(row[i - 1], up[i], up[i - 1]));
        }
        start = end;
    }
}

/// A byte histogram counted in four interleaved tables, so that a run of one value (residuals
/// are mostly 0) does not wait on its own previous increment; [`ByteCounts::total`] sums them.
pub(super) struct ByteCounts([[u64; 256]; 4]);

impl Default for ByteCounts {
    fn default() -> ByteCounts {
        ByteCounts([[0; 256]; 4])
    }
}

impl ByteCounts {
    pub(super) fn add(&mut self, bytes: &[u8]) {
        let [t0, t1, t2, t3] = &mut self.0;
        let quads = bytes.chunks_exact(4);
        for &b in quads.remainder() {
            t0[b as usize] += 1;
        }
        for q in quads {
            t0[q[0] as usize] += 1;
            t1[q[1] as usize] += 1;
            t2[q[2] as usize] += 1;
            t3[q[3] as usize] += 1;
        }
    }

    pub(super) fn total(&self) -> [u64; 256] {
        std::array::from_fn(|v| self.0.iter().map(|t| t[v]).sum())
    }
}

/// Counts `(q − prediction) mod 256` of every value of one line into `counts`, through
/// `scratch` (any contents; left holding the residuals).
pub(super) fn add_residuals(
    line: &[u8],
    width: usize,
    counts: &mut ByteCounts,
    scratch: &mut Vec<u8>,
) {
    scratch.resize(line.len(), 0);
    residuals_into(line, width, scratch);
    counts.add(scratch);
}

/// Appends `(q − prediction) mod 256` of every value of one line.
pub(super) fn push_residuals(line: &[u8], width: usize, out: &mut Vec<u8>) {
    let start = out.len();
    out.resize(start + line.len(), 0);
    residuals_into(line, width, &mut out[start..]);
}

/// Turns one line of residuals back into its q, in place.
pub(super) fn undo_residuals(line: &mut [u8], width: usize) {
    for k in 0..line.len() {
        line[k] = line[k].wrapping_add(predict(line, k, width));
    }
}

/// Predictor widths the encoder tries besides 0 (1D), when shorter than the line: texel grids
/// of a box face are T × T with T typically 8 or 16.
pub const PREDICTOR_WIDTHS: [u16; 10] = [4, 6, 8, 12, 16, 24, 32, 48, 64, 128];

/// Order-0 entropy in bits of a byte histogram (the cheap size estimate of the encoder).
fn entropy_bits(hist: &[u64; 256]) -> f64 {
    let n: u64 = hist.iter().sum();
    if n == 0 {
        return 0.0;
    }
    let n = n as f64;
    hist.iter()
        .filter(|&&c| c > 0)
        .map(|&c| {
            let c = c as f64;
            -c * (c / n).log2()
        })
        .sum()
}

/// Of width 0 and the [`PREDICTOR_WIDTHS`] shorter than a line of `n`, the one whose residuals
/// of `lines` (lines of `n` q each, contiguous) have the least order-0 entropy, with that
/// entropy in bits (ties keep the earlier candidate, so the choice is deterministic). Widths 1
/// and ≥ n predict exactly like 0 and are never chosen.
pub fn best_predictor_width(lines: &[u8], n: usize) -> (u16, f64) {
    let mut best = (0u16, f64::INFINITY);
    let mut scratch = Vec::with_capacity(n);
    for width in std::iter::once(0).chain(PREDICTOR_WIDTHS) {
        if width != 0 && width as usize >= n {
            continue;
        }
        let mut counts = ByteCounts::default();
        if n > 0 {
            for line in lines.chunks_exact(n) {
                add_residuals(line, width as usize, &mut counts, &mut scratch);
            }
        }
        let bits = entropy_bits(&counts.total());
        if bits < best.1 {
            best = (width, bits);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::median;

    /// The branchless median is LOCO-I's, case by case, for every byte triple.
    #[test]
    fn median_is_the_loco_i_predictor_for_every_triple() {
        let loco_i = |a: i32, b: i32, c: i32| {
            if c >= a.max(b) {
                a.min(b)
            } else if c <= a.min(b) {
                a.max(b)
            } else {
                a + b - c
            }
        };
        for a in 0..=255u8 {
            for b in 0..=255u8 {
                for c in 0..=255u8 {
                    let want = loco_i(a as i32, b as i32, c as i32);
                    assert_eq!(median(a, b, c) as i32, want, "({a}, {b}, {c})");
                }
            }
        }
    }
}
