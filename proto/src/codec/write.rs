//! Writing one matrix: `rows u32, cols u32, codec u8` then its values in the codec
//! ([`write_matrix`], on a chosen 8-bit grid [`write_matrix_grid`], predicted with a given width
//! [`write_matrix_predicted`]), or an 8-bit matrix in the smaller of its plain and predicted
//! forms ([`write_matrix_smallest`], what the bundle writer calls).
//!
//! Invariant: a matrix takes exactly `9 + codec.value_bytes(rows, cols)` bytes, and its plain and
//! predicted forms decode to the same bits.

use crate::wire::Writer;

use super::predict::{best_predictor_width, line_len, push_residuals, to_lines, u8_form};
use super::quantize::{quantize_matrix, U8Grid};
use super::MatrixCodec;

/// Writes `rows, cols, codec` and the values in `codec`.
pub fn write_matrix(w: &mut Writer, data: &[f32], rows: usize, cols: usize, codec: MatrixCodec) {
    write_matrix_grid(w, data, rows, cols, codec, U8Grid::FULL)
}

/// [`write_matrix`] on an 8-bit `grid` (the bytes decode like any 8-bit matrix). A
/// predicted codec (tags 4/5) uses the predictor width of [`best_predictor_width`].
pub fn write_matrix_grid(
    w: &mut Writer,
    data: &[f32],
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    grid: U8Grid,
) {
    debug_assert_eq!(data.len(), rows * cols);
    match codec {
        MatrixCodec::F32 => {
            write_header(w, rows, cols, codec);
            for v in data {
                w.f32(*v);
            }
        }
        MatrixCodec::F16 => {
            write_header(w, rows, cols, codec);
            for v in data {
                w.bytes
                    .extend_from_slice(&half::f16::from_f32(*v).to_bits().to_le_bytes());
            }
        }
        MatrixCodec::U8Columns | MatrixCodec::U8Rows => {
            let (params, q) = quantize_matrix(data, rows, cols, codec.per_column(), grid);
            write_plain(w, rows, cols, codec, &params, &q);
        }
        MatrixCodec::U8ColumnsPredicted | MatrixCodec::U8RowsPredicted => {
            let (params, q) = quantize_matrix(data, rows, cols, codec.per_column(), grid);
            write_predicted_from_q(w, rows, cols, codec, &params, &q, None);
        }
    }
}

/// Writes a matrix in `codec` on the 8-bit `grid`, an 8-bit one in the smaller of its plain and
/// predicted forms: the predicted one (tag 4/5) when the order-0 entropy of its residuals, plus
/// the 16 bits of the width, is below that of the plain q bytes. Returns the codec written. The matrix is
/// quantized once and its predictor width searched once: what the bundle writer calls.
pub fn write_matrix_smallest(
    w: &mut Writer,
    data: &[f32],
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    grid: U8Grid,
) -> MatrixCodec {
    if !codec.is_u8() || rows * cols == 0 {
        write_matrix_grid(w, data, rows, cols, codec, grid);
        return codec;
    }
    let plain = codec.unpredicted();
    let (params, q) = quantize_matrix(data, rows, cols, plain.per_column(), grid);
    let ((chosen, width), lines) = u8_form(&q, rows, cols, plain);
    if chosen.is_predicted() {
        write_predicted(w, rows, cols, chosen, &params, &lines, width);
    } else {
        write_plain(w, rows, cols, chosen, &params, &q);
    }
    chosen
}

/// Writes the plain 8-bit form (tag 2/3) from its pairs and row-major q.
fn write_plain(
    w: &mut Writer,
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    params: &[(f32, f32)],
    q: &[u8],
) {
    write_header(w, rows, cols, codec);
    write_pairs(w, params);
    w.bytes.extend_from_slice(q);
}

/// Writes a predicted matrix (tag 4/5) from its pairs and row-major q, with `width`, or with
/// the best width ([`best_predictor_width`]) when None.
fn write_predicted_from_q(
    w: &mut Writer,
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    params: &[(f32, f32)],
    q: &[u8],
    width: Option<u16>,
) {
    let lines = to_lines(q, rows, cols, codec.per_column());
    let width =
        width.unwrap_or_else(|| best_predictor_width(&lines, line_len(rows, cols, codec)).0);
    write_predicted(w, rows, cols, codec, params, &lines, width);
}

/// [`write_matrix_grid`] in a predicted codec (tag 4 or 5; the 8-bit codec of the same side
/// otherwise) with a given predictor `width` (0: 1D).
pub fn write_matrix_predicted(
    w: &mut Writer,
    data: &[f32],
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    grid: U8Grid,
    width: u16,
) {
    debug_assert_eq!(data.len(), rows * cols);
    let codec = codec.predicted();
    debug_assert!(codec.is_predicted(), "{codec:?}");
    let (params, q) = quantize_matrix(data, rows, cols, codec.per_column(), grid);
    write_predicted_from_q(w, rows, cols, codec, &params, &q, Some(width));
}

/// `rows, cols, codec`.
fn write_header(w: &mut Writer, rows: usize, cols: usize, codec: MatrixCodec) {
    w.u32(rows as u32);
    w.u32(cols as u32);
    w.u8(codec.tag());
}

fn write_pairs(w: &mut Writer, params: &[(f32, f32)]) {
    for (offset, scale) in params {
        w.f32(*offset);
        w.f32(*scale);
    }
}

/// Header, width, pairs and residuals of a predicted matrix whose q are given line by line.
fn write_predicted(
    w: &mut Writer,
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    params: &[(f32, f32)],
    lines: &[u8],
    width: u16,
) {
    write_header(w, rows, cols, codec);
    w.bytes.extend_from_slice(&width.to_le_bytes());
    write_pairs(w, params);
    let n = line_len(rows, cols, codec);
    if n > 0 {
        for line in lines.chunks_exact(n) {
            push_residuals(line, width as usize, &mut w.bytes);
        }
    }
}
