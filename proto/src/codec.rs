//! Matrix codecs of the bundle: how one operator's values are stored on the wire.
//!
//! Every operator matrix is written as `rows u32, cols u32, codec u8` then its values:
//! - [`MatrixCodec::F32`]: `rows·cols` little-endian f32 (lossless);
//! - [`MatrixCodec::F16`]: `rows·cols` IEEE binary16 (about 3 significant digits);
//! - [`MatrixCodec::U8Columns`]: per column an `(offset f32, scale f32)` pair, then `rows·cols`
//!   bytes q, value = offset + scale·q; [`MatrixCodec::U8Rows`]: the same with one pair per row.
//!   The encoder puts the pairs on the shorter side, which for our operators is the side of the
//!   modes (U_b is texels × r: per column; T_d→b is r × texels: per row), so every mode has its
//!   own range.
//! - [`MatrixCodec::U8ColumnsPredicted`] (tag 4) and [`MatrixCodec::U8RowsPredicted`] (tag 5):
//!   the values of tags 2 and 3, stored as `width u16`, the same pairs, then the q of each line
//!   (tag 4: column by column; tag 5: row by row) as prediction residuals
//!   `(q − pred) mod 256`, so lossless: a tag-4/5 matrix decodes to the bits of the tag-2/3
//!   matrix with the same q.
//!
//! Values are row-major (the predicted forms' residuals line by line). Decoding returns f32
//! whatever the codec, and never allocates more than the bytes it was given can fill (sizes are
//! checked against the remaining input before any allocation).
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
//! ([`write_matrix_smallest`]); with T × T faces the width T wins, and zstd codes the operators in
//! fewer bytes (maze at T = 8: shapes −25%, transport −19%, DRT −9%).
//!
//! The error a codec adds to a matrix is its relative RMS error `‖Q(M) − M‖_F / ‖M‖_F`
//! ([`codec_error`]); [`choose_encoding`] picks the smallest codec within a budget.
//!
//! Coarser 8-bit grids: the encoder may use only every `step`-th level of the 256 (`step` in
//! [`U8_STEPS`], a divisor of 255, so the line's maximum stays on the grid): q is a multiple of
//! `step`, which leaves the wire format and the decoder unchanged but gives zstd only
//! `255/step + 1` distinct bytes to code (86 levels ≈ 6.4 bits, 52 ≈ 5.7, 18 ≈ 4.2). With a
//! budget the encoder takes the coarsest step within it. The runtime still sees an ordinary
//! 8-bit grid.

use crate::wire::{Reader, WireError, Writer};

/// How a matrix's values are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum MatrixCodec {
    F32,
    F16,
    U8Columns,
    U8Rows,
    /// [`MatrixCodec::U8Columns`]'s values, each column's q stored as prediction residuals.
    U8ColumnsPredicted,
    /// [`MatrixCodec::U8Rows`]'s values, each row's q stored as prediction residuals.
    U8RowsPredicted,
}

impl MatrixCodec {
    fn tag(self) -> u8 {
        match self {
            MatrixCodec::F32 => 0,
            MatrixCodec::F16 => 1,
            MatrixCodec::U8Columns => 2,
            MatrixCodec::U8Rows => 3,
            MatrixCodec::U8ColumnsPredicted => 4,
            MatrixCodec::U8RowsPredicted => 5,
        }
    }

    fn from_tag(tag: u8) -> Option<MatrixCodec> {
        Some(match tag {
            0 => MatrixCodec::F32,
            1 => MatrixCodec::F16,
            2 => MatrixCodec::U8Columns,
            3 => MatrixCodec::U8Rows,
            4 => MatrixCodec::U8ColumnsPredicted,
            5 => MatrixCodec::U8RowsPredicted,
            _ => return None,
        })
    }

    /// Short name for reports (`f32`, `f16`, `u8`; the predicted forms are `u8` too: they
    /// decode to the same values).
    pub fn name(self) -> &'static str {
        match self {
            MatrixCodec::F32 => "f32",
            MatrixCodec::F16 => "f16",
            _ => "u8",
        }
    }

    /// Whether values are 8-bit `offset + scale·q` (tags 2–5).
    pub fn is_u8(self) -> bool {
        !matches!(self, MatrixCodec::F32 | MatrixCodec::F16)
    }

    /// Whether the q are stored as prediction residuals (tags 4 and 5).
    pub fn is_predicted(self) -> bool {
        matches!(
            self,
            MatrixCodec::U8ColumnsPredicted | MatrixCodec::U8RowsPredicted
        )
    }

    /// The codec with the same decoded values and plain q bytes (tags 4/5 → 2/3; others
    /// unchanged).
    pub fn unpredicted(self) -> MatrixCodec {
        match self {
            MatrixCodec::U8ColumnsPredicted => MatrixCodec::U8Columns,
            MatrixCodec::U8RowsPredicted => MatrixCodec::U8Rows,
            c => c,
        }
    }

    /// The predicted form of an 8-bit codec (tags 2/3 → 4/5; others unchanged).
    pub fn predicted(self) -> MatrixCodec {
        match self {
            MatrixCodec::U8Columns => MatrixCodec::U8ColumnsPredicted,
            MatrixCodec::U8Rows => MatrixCodec::U8RowsPredicted,
            c => c,
        }
    }

    /// Whether the 8-bit `(offset, scale)` pairs are per column (tags 2 and 4).
    fn per_column(self) -> bool {
        matches!(
            self,
            MatrixCodec::U8Columns | MatrixCodec::U8ColumnsPredicted
        )
    }

    /// The 8-bit codec with its (offset, scale) pairs on the shorter side of a rows × cols
    /// matrix.
    pub fn u8_for(rows: usize, cols: usize) -> MatrixCodec {
        if cols <= rows {
            MatrixCodec::U8Columns
        } else {
            MatrixCodec::U8Rows
        }
    }

    /// Bytes of the values of a rows × cols matrix in this codec (without the 9-byte header).
    pub fn value_bytes(self, rows: usize, cols: usize) -> usize {
        let n = rows * cols;
        match self {
            MatrixCodec::F32 => 4 * n,
            MatrixCodec::F16 => 2 * n,
            MatrixCodec::U8Columns => n + 8 * cols,
            MatrixCodec::U8Rows => n + 8 * rows,
            MatrixCodec::U8ColumnsPredicted => 2 + n + 8 * cols,
            MatrixCodec::U8RowsPredicted => 2 + n + 8 * rows,
        }
    }
}

/// Which codec the encoder uses for each matrix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CodecPolicy {
    /// Every matrix in one codec (any of the 8-bit codecs means "8-bit on the shorter side";
    /// the bundle writer then stores the q plain or predicted, whichever is smaller).
    Fixed(MatrixCodec),
    /// Per matrix, the smallest codec whose [`codec_error`] is at most this relative RMS error.
    Budget(f64),
}

/// `(offset, scale)` of an 8-bit line (a column or a row) with values in `[lo, hi]`.
fn u8_line_params(lo: f32, hi: f32) -> (f32, f32) {
    if hi > lo {
        (lo, (hi - lo) / 255.0)
    } else {
        (lo, 0.0)
    }
}

/// Steps of the 8-bit grid the encoder may use (divisors of 255), coarsest first.
pub const U8_STEPS: [u8; 5] = [17, 15, 5, 3, 1];

/// Report name of the 8-bit codec with `step`.
pub fn u8_step_name(step: u8) -> &'static str {
    match step {
        17 => "u8 (16 levels)",
        15 => "u8 (18 levels)",
        5 => "u8 (52 levels)",
        3 => "u8 (86 levels)",
        _ => "u8",
    }
}

fn quantize_u8(v: f32, offset: f32, scale: f32, step: u8) -> u8 {
    if scale > 0.0 {
        let step = step.max(1) as f32;
        let q = ((v - offset) / (scale * step)).round() * step;
        q.clamp(0.0, 255.0) as u8
    } else {
        0
    }
}

/// Per-line (offset, scale) for an 8-bit codec; lines are columns or rows.
fn u8_params(data: &[f32], rows: usize, cols: usize, per_column: bool) -> Vec<(f32, f32)> {
    let lines = if per_column { cols } else { rows };
    let mut lo = vec![f32::INFINITY; lines];
    let mut hi = vec![f32::NEG_INFINITY; lines];
    for i in 0..rows {
        for j in 0..cols {
            let v = data[i * cols + j];
            let l = if per_column { j } else { i };
            lo[l] = lo[l].min(v);
            hi[l] = hi[l].max(v);
        }
    }
    lo.iter()
        .zip(&hi)
        .map(|(&l, &h)| {
            if l.is_finite() {
                u8_line_params(l, h)
            } else {
                (0.0, 0.0)
            }
        })
        .collect()
}

/// The value of row-major element `k` of a `cols`-wide 8-bit matrix with line pairs `params`.
#[inline]
fn u8_value(params: &[(f32, f32)], per_column: bool, cols: usize, k: usize, q: u8) -> f32 {
    let (offset, scale) = params[if per_column { k % cols } else { k / cols }];
    offset + scale * q as f32
}

/// The values a matrix decodes to after a round trip through `codec`.
pub fn round_trip(data: &[f32], rows: usize, cols: usize, codec: MatrixCodec) -> Vec<f32> {
    round_trip_step(data, rows, cols, codec, 1)
}

/// [`round_trip`] with an 8-bit grid `step` (ignored by the other codecs).
pub fn round_trip_step(
    data: &[f32],
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    step: u8,
) -> Vec<f32> {
    match codec {
        MatrixCodec::F32 => data.to_vec(),
        MatrixCodec::F16 => data
            .iter()
            .map(|v| half::f16::from_f32(*v).to_f32())
            .collect(),
        _ => {
            let per_column = codec.per_column();
            let (params, q) = quantize_matrix(data, rows, cols, per_column, step);
            q.iter()
                .enumerate()
                .map(|(k, q)| u8_value(&params, per_column, cols, k, *q))
                .collect()
        }
    }
}

/// Relative RMS error `‖Q(M) − M‖_F / ‖M‖_F` that `codec` adds to a matrix (0 for an all-zero
/// matrix stored exactly; infinite when the codec cannot represent a value, e.g. f16 overflow).
pub fn codec_error(data: &[f32], rows: usize, cols: usize, codec: MatrixCodec) -> f64 {
    codec_error_step(data, rows, cols, codec, 1)
}

/// [`codec_error`] with an 8-bit grid `step`.
pub fn codec_error_step(
    data: &[f32],
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    step: u8,
) -> f64 {
    let back = round_trip_step(data, rows, cols, codec, step);
    let (mut diff, mut norm) = (0.0f64, 0.0f64);
    for (a, b) in data.iter().zip(&back) {
        let d = *b as f64 - *a as f64;
        diff += d * d;
        norm += (*a as f64) * (*a as f64);
    }
    if !diff.is_finite() {
        return f64::INFINITY;
    }
    if norm == 0.0 {
        return if diff == 0.0 { 0.0 } else { f64::INFINITY };
    }
    (diff / norm).sqrt()
}

/// The codec `policy` gives a matrix, with the error it adds (full 8-bit grid).
pub fn choose_codec(
    data: &[f32],
    rows: usize,
    cols: usize,
    policy: CodecPolicy,
) -> (MatrixCodec, f64) {
    match policy {
        CodecPolicy::Budget(_) => {
            let (codec, step, error) = choose_encoding(data, rows, cols, policy);
            if step == 1 {
                return (codec, error);
            }
            (codec, codec_error(data, rows, cols, codec))
        }
        _ => {
            let (codec, _, error) = choose_encoding(data, rows, cols, policy);
            (codec, error)
        }
    }
}

/// The codec and 8-bit grid step `policy` gives a matrix, with the error they add. A budget
/// takes the coarsest 8-bit grid within it, else f16, else f32; a fixed codec uses the full grid.
pub fn choose_encoding(
    data: &[f32],
    rows: usize,
    cols: usize,
    policy: CodecPolicy,
) -> (MatrixCodec, u8, f64) {
    let (codec, error) = match policy {
        CodecPolicy::Fixed(codec) if codec.is_u8() => {
            let codec = MatrixCodec::u8_for(rows, cols);
            (codec, codec_error(data, rows, cols, codec))
        }
        CodecPolicy::Fixed(codec) => (codec, codec_error(data, rows, cols, codec)),
        CodecPolicy::Budget(budget) => {
            let u8_codec = MatrixCodec::u8_for(rows, cols);
            for step in U8_STEPS {
                let e = codec_error_step(data, rows, cols, u8_codec, step);
                if e <= budget {
                    return (u8_codec, step, e);
                }
            }
            let e = codec_error(data, rows, cols, MatrixCodec::F16);
            if e <= budget {
                (MatrixCodec::F16, e)
            } else {
                (MatrixCodec::F32, 0.0)
            }
        }
    };
    (codec, 1, error)
}

/// Writes `rows, cols, codec` and the values in `codec`.
pub fn write_matrix(w: &mut Writer, data: &[f32], rows: usize, cols: usize, codec: MatrixCodec) {
    write_matrix_step(w, data, rows, cols, codec, 1)
}

/// [`write_matrix`] on an 8-bit grid with `step` (the bytes decode like any 8-bit matrix). A
/// predicted codec (tags 4/5) uses the predictor width of [`best_predictor_width`].
pub fn write_matrix_step(
    w: &mut Writer,
    data: &[f32],
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    step: u8,
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
            let (params, q) = quantize_matrix(data, rows, cols, codec.per_column(), step);
            write_plain(w, rows, cols, codec, &params, &q);
        }
        MatrixCodec::U8ColumnsPredicted | MatrixCodec::U8RowsPredicted => {
            let (params, q) = quantize_matrix(data, rows, cols, codec.per_column(), step);
            write_predicted_from_q(w, rows, cols, codec, &params, &q, None);
        }
    }
}

/// Writes a matrix in `codec` on the grid `step`, an 8-bit one in the smaller of its plain and
/// predicted forms: the predicted one (tag 4/5) when the order-0 entropy of its residuals, plus
/// the 16 bits of the width, is below that of the plain q bytes. Returns the codec written. The matrix is
/// quantized once and its predictor width searched once: what the bundle writer calls.
pub fn write_matrix_smallest(
    w: &mut Writer,
    data: &[f32],
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    step: u8,
) -> MatrixCodec {
    if !codec.is_u8() || rows * cols == 0 {
        write_matrix_step(w, data, rows, cols, codec, step);
        return codec;
    }
    let plain = codec.unpredicted();
    let (params, q) = quantize_matrix(data, rows, cols, plain.per_column(), step);
    let ((chosen, width), lines) = u8_form(&q, rows, cols, plain);
    if chosen.is_predicted() {
        write_predicted(w, rows, cols, chosen, &params, &lines, width);
    } else {
        write_plain(w, rows, cols, chosen, &params, &q);
    }
    chosen
}

/// Of an 8-bit matrix's plain codec `plain` and its predicted form, the smaller by the
/// order-0 entropy estimate (the predicted one only when its residuals, plus the 16 bits of
/// the width, take fewer bits than the plain q), with the predictor width; and the q line by
/// line (what a predicted form stores; a plain one ignores the order).
fn u8_form(
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

/// [`write_matrix_step`] in a predicted codec (tag 4 or 5; the 8-bit codec of the same side
/// otherwise) with a given predictor `width` (0: 1D).
pub fn write_matrix_predicted(
    w: &mut Writer,
    data: &[f32],
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    step: u8,
    width: u16,
) {
    debug_assert_eq!(data.len(), rows * cols);
    let codec = codec.predicted();
    debug_assert!(codec.is_predicted(), "{codec:?}");
    let (params, q) = quantize_matrix(data, rows, cols, codec.per_column(), step);
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

/// The line-wise `(offset, scale)` pairs and the row-major q of a matrix on an 8-bit grid.
fn quantize_matrix(
    data: &[f32],
    rows: usize,
    cols: usize,
    per_column: bool,
    step: u8,
) -> (Vec<(f32, f32)>, Vec<u8>) {
    let params = u8_params(data, rows, cols, per_column);
    let mut q = Vec::with_capacity(rows * cols);
    for i in 0..rows {
        for j in 0..cols {
            let (offset, scale) = params[if per_column { j } else { i }];
            q.push(quantize_u8(data[i * cols + j], offset, scale, step));
        }
    }
    (params, q)
}

/// Length of one line (a column for per-column codecs, else a row).
fn line_len(rows: usize, cols: usize, codec: MatrixCodec) -> usize {
    if codec.per_column() {
        rows
    } else {
        cols
    }
}

/// Row-major q rearranged so that each line (column or row) is contiguous.
fn to_lines(q: &[u8], rows: usize, cols: usize, per_column: bool) -> Vec<u8> {
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
fn predict(line: &[u8], k: usize, width: usize) -> u8 {
    if width == 0 {
        return if k > 0 { line[k - 1] } else { 0 };
    }
    let has_left = !k.is_multiple_of(width);
    let has_up = k >= width;
    match (has_left, has_up) {
        (false, false) => 0,
        (true, false) => line[k - 1],
        (false, true) => line[k - width],
        (true, true) => {
            let (a, b, c) = (
                line[k - 1] as i32,
                line[k - width] as i32,
                line[k - width - 1] as i32,
            );
            // LOCO-I / JPEG-LS median of (a, b, a + b − c): always within [min, max] of a, b.
            let p = if c >= a.max(b) {
                a.min(b)
            } else if c <= a.min(b) {
                a.max(b)
            } else {
                a + b - c
            };
            p as u8
        }
    }
}

/// Appends `(q − prediction) mod 256` of every value of one line.
fn push_residuals(line: &[u8], width: usize, out: &mut Vec<u8>) {
    out.extend((0..line.len()).map(|k| line[k].wrapping_sub(predict(line, k, width))));
}

/// Turns one line of residuals back into its q, in place.
fn undo_residuals(line: &mut [u8], width: usize) {
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
                for k in 0..n {
                    hist[line[k].wrapping_sub(predict(line, k, width as usize)) as usize] += 1;
                }
            }
        }
        let bits = entropy_bits(&hist);
        if bits < best.1 {
            best = (width, bits);
        }
    }
    best
}

/// A decoded matrix: `(rows, cols, row-major values, codec)`. Values may be non-finite only if
/// the bytes say so; callers validate.
pub type DecodedMatrix = (u32, u32, Vec<f32>, MatrixCodec);

/// Reads what [`write_matrix`] wrote.
pub fn read_matrix(r: &mut Reader) -> Result<DecodedMatrix, WireError> {
    let rows = r.u32()?;
    let cols = r.u32()?;
    let tag = r.u8()?;
    let codec = MatrixCodec::from_tag(tag)
        .ok_or_else(|| WireError::Invalid(format!("unknown matrix codec {tag}")))?;
    let n = rows as u64 * cols as u64;
    let needed = match codec {
        MatrixCodec::F32 => n.checked_mul(4),
        MatrixCodec::F16 => n.checked_mul(2),
        MatrixCodec::U8Columns => n.checked_add(8 * cols as u64),
        MatrixCodec::U8Rows => n.checked_add(8 * rows as u64),
        MatrixCodec::U8ColumnsPredicted => n.checked_add(2 + 8 * cols as u64),
        MatrixCodec::U8RowsPredicted => n.checked_add(2 + 8 * rows as u64),
    };
    match needed {
        Some(b) if b <= r.remaining() as u64 => {}
        _ => {
            return Err(WireError::Truncated {
                offset: r.position(),
                needed: needed.unwrap_or(u64::MAX).min(usize::MAX as u64) as usize,
                available: r.remaining(),
            })
        }
    }
    let n = n as usize;
    let data = match codec {
        MatrixCodec::F32 => r
            .take(4 * n)?
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect(),
        MatrixCodec::F16 => r
            .take(2 * n)?
            .chunks_exact(2)
            .map(|c| half::f16::from_bits(u16::from_le_bytes([c[0], c[1]])).to_f32())
            .collect(),
        _ => {
            let per_column = codec.per_column();
            let width = if codec.is_predicted() {
                let b = r.take(2)?;
                u16::from_le_bytes([b[0], b[1]]) as usize
            } else {
                0
            };
            let lines = if per_column { cols } else { rows } as usize;
            let mut params = Vec::with_capacity(lines);
            for _ in 0..lines {
                params.push((r.f32()?, r.f32()?));
            }
            let bytes = r.take(n)?;
            let cols = cols as usize;
            let value = |k: usize, q: u8| u8_value(&params, per_column, cols, k, q);
            if !codec.is_predicted() {
                bytes
                    .iter()
                    .enumerate()
                    .map(|(k, q)| value(k, *q))
                    .collect()
            } else {
                let mut q = bytes.to_vec();
                let len = line_len(rows as usize, cols, codec);
                if len > 0 {
                    for line in q.chunks_exact_mut(len) {
                        undo_residuals(line, width);
                    }
                }
                if per_column {
                    // Line-major (column by column) back to row-major.
                    let rows = rows as usize;
                    (0..n)
                        .map(|k| value(k, q[(k % cols) * rows + k / cols]))
                        .collect()
                } else {
                    q.iter().enumerate().map(|(k, q)| value(k, *q)).collect()
                }
            }
        }
    };
    Ok((rows, cols, data, codec))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn sample_matrix(rows: usize, cols: usize) -> Vec<f32> {
        // A smooth matrix with one large column, like a U_b with a dominant first mode.
        (0..rows * cols)
            .map(|k| {
                let (i, j) = (k / cols, k % cols);
                let base = ((i as f32 * 0.37 + j as f32 * 1.3).sin()) / (1.0 + j as f32);
                if j == 0 {
                    10.0 + base
                } else {
                    base
                }
            })
            .collect()
    }

    #[test]
    fn f32_is_lossless_and_u8_error_is_within_half_a_step_per_value() {
        let (rows, cols) = (40, 7);
        let m = sample_matrix(rows, cols);
        assert_eq!(codec_error(&m, rows, cols, MatrixCodec::F32), 0.0);
        let back = round_trip(&m, rows, cols, MatrixCodec::U8Columns);
        for j in 0..cols {
            let col: Vec<f32> = (0..rows).map(|i| m[i * cols + j]).collect();
            let lo = col.iter().cloned().fold(f32::INFINITY, f32::min);
            let hi = col.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
            let half_step = (hi - lo) / 255.0 / 2.0;
            for i in 0..rows {
                let d = (back[i * cols + j] - m[i * cols + j]).abs();
                assert!(
                    d <= half_step * 1.001 + 1e-6,
                    "({i},{j}): {d} > {half_step}"
                );
            }
        }
        let e8 = codec_error(&m, rows, cols, MatrixCodec::U8Columns);
        let e16 = codec_error(&m, rows, cols, MatrixCodec::F16);
        assert!(e16 < e8, "f16 {e16} should beat u8 {e8}");
        assert!(e8 < 0.01 && e16 < 1e-3, "u8 {e8}, f16 {e16}");
    }

    #[test]
    fn budget_picks_the_smallest_codec_that_fits() {
        let (rows, cols) = (64, 5);
        let m = sample_matrix(rows, cols);
        let e8 = codec_error(&m, rows, cols, MatrixCodec::U8Columns);
        let e16 = codec_error(&m, rows, cols, MatrixCodec::F16);
        assert_eq!(
            choose_codec(&m, rows, cols, CodecPolicy::Budget(e8 * 1.01)).0,
            MatrixCodec::U8Columns
        );
        assert_eq!(
            choose_codec(&m, rows, cols, CodecPolicy::Budget(e8 * 0.99)).0,
            MatrixCodec::F16
        );
        assert_eq!(
            choose_codec(&m, rows, cols, CodecPolicy::Budget(e16 * 0.5)).0,
            MatrixCodec::F32
        );
        // Wide matrices put their ranges on rows.
        assert_eq!(
            choose_codec(&m, cols, rows, CodecPolicy::Fixed(MatrixCodec::U8Columns)).0,
            MatrixCodec::U8Rows
        );
    }

    #[test]
    fn f16_overflow_is_an_infinite_error_so_the_budget_refuses_it() {
        let m = vec![1.0e6f32, 2.0, 3.0, 4.0];
        assert!(codec_error(&m, 2, 2, MatrixCodec::F16).is_infinite());
        let (codec, _) = choose_codec(&m, 2, 2, CodecPolicy::Budget(0.01));
        assert_ne!(codec, MatrixCodec::F16);
    }

    #[test]
    fn constant_and_zero_lines_quantise_exactly() {
        let m = vec![0.0, 2.5, 0.0, 2.5, 0.0, 2.5];
        for codec in [
            MatrixCodec::U8Columns,
            MatrixCodec::U8Rows,
            MatrixCodec::F16,
        ] {
            assert_eq!(round_trip(&m, 3, 2, codec), m, "{codec:?}");
        }
    }

    proptest! {
        #[test]
        fn every_codec_round_trips_through_the_wire(
            rows in 0usize..9, cols in 0usize..9,
            seed in proptest::collection::vec(-1.0e3f32..1.0e3, 81),
            tag in 0u8..6,
        ) {
            let data: Vec<f32> = seed[..rows * cols].to_vec();
            let codec = MatrixCodec::from_tag(tag).unwrap();
            let mut w = Writer::new();
            write_matrix(&mut w, &data, rows, cols, codec);
            prop_assert_eq!(w.bytes.len(), 9 + codec.value_bytes(rows, cols));
            let mut r = Reader::new(&w.bytes);
            let (r2, c2, back, codec2) = read_matrix(&mut r).unwrap();
            prop_assert_eq!((r2 as usize, c2 as usize, codec2), (rows, cols, codec));
            prop_assert_eq!(back, round_trip(&data, rows, cols, codec));
            prop_assert_eq!(r.remaining(), 0);
        }

        #[test]
        fn reading_arbitrary_bytes_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..128)) {
            let mut r = Reader::new(&bytes);
            let _ = read_matrix(&mut r);
        }

        /// Any bytes after a predicted header (small or huge sizes, any width) decode to `Ok`
        /// or `Err` without panicking, and `Ok` consumes exactly the matrix's bytes.
        #[test]
        fn reading_arbitrary_predicted_matrices_never_panics(
            rows in prop_oneof![0u32..7, any::<u32>()],
            cols in prop_oneof![0u32..7, any::<u32>()],
            tag in 4u8..6,
            rest in proptest::collection::vec(any::<u8>(), 0..160),
        ) {
            let mut bytes = rows.to_le_bytes().to_vec();
            bytes.extend_from_slice(&cols.to_le_bytes());
            bytes.push(tag);
            bytes.extend_from_slice(&rest);
            let mut r = Reader::new(&bytes);
            if let Ok((r2, c2, values, codec)) = read_matrix(&mut r) {
                prop_assert_eq!((r2, c2), (rows, cols));
                prop_assert_eq!(values.len(), rows as usize * cols as usize);
                let used = bytes.len() - r.remaining();
                prop_assert_eq!(used, 9 + codec.value_bytes(rows as usize, cols as usize));
            }
        }

        /// Tags 4/5 with any width decode to the bits of tags 2/3 for the same q.
        #[test]
        fn predicted_matrices_decode_like_plain_ones(
            rows in 0usize..12, cols in 0usize..12,
            seed in proptest::collection::vec(-1.0e3f32..1.0e3, 144),
            per_column in any::<bool>(),
            step in proptest::sample::select(U8_STEPS.to_vec()),
            width in prop_oneof![0u16..20, any::<u16>()],
        ) {
            let data = &seed[..rows * cols];
            let plain = if per_column { MatrixCodec::U8Columns } else { MatrixCodec::U8Rows };
            let (back, predicted) = predicted_and_plain(data, rows, cols, plain, step, width);
            prop_assert_eq!(bits(&back), bits(&predicted));
        }
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    fn decode(bytes: &[u8]) -> DecodedMatrix {
        let mut r = Reader::new(bytes);
        let m = read_matrix(&mut r).unwrap();
        assert_eq!(r.remaining(), 0);
        m
    }

    /// Decoded values of `data` written in `plain` (tag 2/3) and in its predicted form with
    /// `width`, after checking the predicted bytes' size and codec.
    fn predicted_and_plain(
        data: &[f32],
        rows: usize,
        cols: usize,
        plain: MatrixCodec,
        step: u8,
        width: u16,
    ) -> (Vec<f32>, Vec<f32>) {
        let mut w = Writer::new();
        write_matrix_step(&mut w, data, rows, cols, plain, step);
        let (_, _, back, codec) = decode(&w.bytes);
        assert_eq!(codec, plain);
        let mut w = Writer::new();
        write_matrix_predicted(&mut w, data, rows, cols, plain, step, width);
        let predicted = plain.predicted();
        assert_eq!(w.bytes.len(), 9 + predicted.value_bytes(rows, cols));
        assert_eq!(&w.bytes[9..11], &width.to_le_bytes());
        let (r2, c2, values, codec) = decode(&w.bytes);
        assert_eq!((r2 as usize, c2 as usize, codec), (rows, cols, predicted));
        (back, values)
    }

    /// Some pseudo-random values with a smooth trend, on every 8-bit line.
    fn noisy_matrix(rows: usize, cols: usize, seed: u64) -> Vec<f32> {
        let mut s = seed;
        (0..rows * cols)
            .map(|k| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let noise = (s >> 40) as f32 / (1u64 << 24) as f32;
                (k as f32 * 0.1).sin() + noise
            })
            .collect()
    }

    #[test]
    fn predicted_forms_round_trip_on_every_shape_and_width() {
        // 1×1, lines of one value, a partial last image row, widths 0, 1, ≥ the line, u16::MAX.
        let shapes = [
            (1, 1),
            (1, 9),
            (9, 1),
            (13, 5),
            (5, 13),
            (64, 3),
            (3, 64),
            (0, 4),
            (4, 0),
            (0, 0),
        ];
        for (rows, cols) in shapes {
            let data = noisy_matrix(rows, cols, (rows * 100 + cols) as u64);
            for plain in [MatrixCodec::U8Columns, MatrixCodec::U8Rows] {
                for step in U8_STEPS {
                    for width in [0, 1, 2, 3, 5, 8, 12, 13, 64, 65, 1000, u16::MAX] {
                        let (back, predicted) =
                            predicted_and_plain(&data, rows, cols, plain, step, width);
                        assert_eq!(
                            bits(&back),
                            bits(&predicted),
                            "{rows}×{cols} {plain:?} step {step} width {width}"
                        );
                        assert_eq!(
                            bits(&back),
                            bits(&round_trip_step(&data, rows, cols, plain, step)),
                        );
                    }
                }
                // The encoder's own width choice decodes the same way too.
                let mut w = Writer::new();
                write_matrix(&mut w, &data, rows, cols, plain.predicted());
                assert_eq!(
                    bits(&decode(&w.bytes).2),
                    bits(&round_trip(&data, rows, cols, plain))
                );
            }
        }
    }

    /// The exact bytes of a small tag-4 matrix: one column of q
    /// `[0, 255, 25, 20, 30, 40]` as an image 2 wide.
    #[test]
    fn predicted_wire_format_is_the_documented_one() {
        let q = [0.0f32, 255.0, 25.0, 20.0, 30.0, 40.0];
        let mut w = Writer::new();
        write_matrix_predicted(&mut w, &q, 6, 1, MatrixCodec::U8Columns, 1, 2);
        let mut want = vec![6, 0, 0, 0, 1, 0, 0, 0, 4, 2, 0];
        want.extend_from_slice(&0.0f32.to_le_bytes());
        want.extend_from_slice(&1.0f32.to_le_bytes());
        // k0 no neighbour: 0; k1 left 0; k2 up 0; k3 median(25, 255, 25 + 255 − 0) = 255;
        // k4 up 25; k5 median(30, 20, 30 + 20 − 25) = 25.
        want.extend_from_slice(&[0, 255, 25, 20u8.wrapping_sub(255), 5, 15]);
        assert_eq!(w.bytes, want);
        assert_eq!(decode(&w.bytes).2, q);
        // 1D: the previous value.
        let mut w = Writer::new();
        write_matrix_predicted(&mut w, &q, 1, 6, MatrixCodec::U8Rows, 1, 0);
        assert_eq!(&w.bytes[8..11], &[5, 0, 0]);
        assert_eq!(
            &w.bytes[19..],
            &[
                0,
                255,
                25u8.wrapping_sub(255),
                20u8.wrapping_sub(25),
                10,
                10
            ]
        );
        assert_eq!(decode(&w.bytes).2, q);
        // The median's three cases.
        let line = [10u8, 20, 30, 0, 10, 20, 15];
        assert_eq!(predict(&[30, 10, 20, 0], 3, 2), 10); // upleft ≥ both: min
        assert_eq!(predict(&[5, 10, 20, 0], 3, 2), 20); // upleft ≤ both: max
        assert_eq!(predict(&[15, 10, 20, 0], 3, 2), 15); // else left + up − upleft
        assert_eq!(predict(&line, 0, 3), 0);
        assert_eq!(predict(&line, 3, 3), 10); // first of an image row: up
        assert_eq!(predict(&line, 2, 3), 20); // first image row: left
    }

    /// Lighting-like data: smooth functions on the 8 × 8 texel grids of six box faces, as a
    /// U_b (texels × r, per column) and a T_d→b (r × texels, per row).
    #[test]
    fn smooth_face_data_is_stored_predicted_and_smaller_after_zstd() {
        let (t, faces, r) = (8usize, 6usize, 12usize);
        let texels = t * t * faces;
        let u_b: Vec<f32> = (0..texels * r)
            .map(|k| {
                let (texel, mode) = (k / r, k % r);
                let (face, j, i) = (texel / (t * t), (texel % (t * t)) / t, texel % t);
                let (x, y) = (i as f32 / t as f32, j as f32 / t as f32);
                let f = mode as f32 + 1.0;
                ((x * f + face as f32).sin() * (y * 0.7 * f).cos() + x * y) / f
            })
            .collect();
        let t_db: Vec<f32> = (0..r * texels)
            .map(|k| u_b[(k % texels) * r + k / texels])
            .collect();
        for (data, rows, cols, plain) in [
            (&u_b, texels, r, MatrixCodec::U8Columns),
            (&t_db, r, texels, MatrixCodec::U8Rows),
        ] {
            for policy in [
                CodecPolicy::Budget(0.02),
                CodecPolicy::Fixed(MatrixCodec::U8Columns),
            ] {
                let (codec, step, _) = choose_encoding(data, rows, cols, policy);
                assert_eq!(codec, plain);
                let chosen =
                    write_matrix_smallest(&mut Writer::new(), data, rows, cols, codec, step);
                assert_eq!(chosen, plain.predicted(), "{plain:?} step {step}");
                let (_, q) = quantize_matrix(data, rows, cols, plain.per_column(), step);
                let lines = to_lines(&q, rows, cols, plain.per_column());
                assert_eq!(best_predictor_width(&lines, texels).0, t as u16);
                let size = |codec| {
                    let mut w = Writer::new();
                    write_matrix_step(&mut w, data, rows, cols, codec, step);
                    let (.., values, _) = decode(&w.bytes);
                    (zstd::bulk::compress(&w.bytes, 9).unwrap().len(), values)
                };
                let (plain_size, plain_values) = size(plain);
                let (predicted_size, values) = size(chosen);
                assert_eq!(bits(&values), bits(&plain_values));
                eprintln!("{plain:?} step {step}: zstd {plain_size} -> {predicted_size}");
                assert!(
                    (predicted_size as f64) < 0.9 * plain_size as f64,
                    "{plain:?} step {step}: {predicted_size} vs {plain_size}"
                );
            }
        }
    }

    #[test]
    fn noise_keeps_the_plain_form() {
        let mut s = 99u64;
        let data: Vec<f32> = (0..64 * 8)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 40) as f32
            })
            .collect();
        for (rows, cols) in [(64, 8), (8, 64)] {
            let codec = MatrixCodec::u8_for(rows, cols);
            assert_eq!(
                write_matrix_smallest(&mut Writer::new(), &data, rows, cols, codec, 1),
                codec
            );
        }
        // Non-8-bit codecs and empty matrices are left alone.
        assert_eq!(
            write_matrix_smallest(&mut Writer::new(), &data, 64, 8, MatrixCodec::F16, 1),
            MatrixCodec::F16
        );
        assert_eq!(
            write_matrix_smallest(&mut Writer::new(), &[], 0, 8, MatrixCodec::U8Columns, 1),
            MatrixCodec::U8Columns
        );
    }
}
