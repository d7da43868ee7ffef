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
    let mut hist = [0u64; 256];
    for &b in q {
        hist[b as usize] += 1;
    }
    let plain_bits = entropy_bits(&hist);
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
/// of left and up.
#[inline]
fn median(left: u8, up: u8, upleft: u8) -> u8 {
    let (a, b, c) = (left as i32, up as i32, upleft as i32);
    let p = if c >= a.max(b) {
        a.min(b)
    } else if c <= a.min(b) {
        a.max(b)
    } else {
        a + b - c
    };
    p as u8
}

/// Counts `(q − prediction) mod 256` of every value of one line into `hist`: what
/// [`predict`] gives, walked image row by image row so that no element needs a division or a
/// branch on its position.
pub(super) fn add_residuals(line: &[u8], width: usize, hist: &mut [u64; 256]) {
    let n = line.len();
    if n == 0 {
        return;
    }
    // The first value has no neighbour; the rest of the first image row (all of the line for
    // width 0) predicts from the left.
    hist[line[0] as usize] += 1;
    let first_row = if width == 0 { n } else { width.min(n) };
    for k in 1..first_row {
        hist[line[k].wrapping_sub(line[k - 1]) as usize] += 1;
    }
    let mut start = first_row;
    while start < n {
        let end = (start + width).min(n);
        // A row's first value predicts from above, the others by the median.
        hist[line[start].wrapping_sub(line[start - width]) as usize] += 1;
        for k in start + 1..end {
            let p = median(line[k - 1], line[k - width], line[k - width - 1]);
            hist[line[k].wrapping_sub(p) as usize] += 1;
        }
        start = end;
    }
}

/// Appends `(q − prediction) mod 256` of every value of one line.
pub(super) fn push_residuals(line: &[u8], width: usize, out: &mut Vec<u8>) {
    out.extend((0..line.len()).map(|k| line[k].wrapping_sub(predict(line, k, width))));
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
    for width in std::iter::once(0).chain(PREDICTOR_WIDTHS) {
        if width != 0 && width as usize >= n {
            continue;
        }
        let mut hist = [0u64; 256];
        if n > 0 {
            for line in lines.chunks_exact(n) {
                add_residuals(line, width as usize, &mut hist);
            }
        }
        let bits = entropy_bits(&hist);
        if bits < best.1 {
            best = (width, bits);
        }
    }
    best
}
