//! 8-bit lines and what every codec gives back: per line (a column or a row) an
//! `(offset, scale)` pair and bytes q with value = offset + scale·q, on the full grid of 256
//! levels or a coarser one; [`round_trip`], the values a matrix decodes to in a codec; and
//! [`codec_error`], the relative RMS error `‖Q(M) − M‖_F / ‖M‖_F` that adds.
//!
//! Coarser 8-bit grids: the encoder may use only every `step`-th level of the 256 (`step` in
//! [`U8_STEPS`], a divisor of 255, so the line's maximum stays on the grid): q is a multiple of
//! `step`, which leaves the wire format and the decoder unchanged but gives zstd only
//! `255/step + 1` distinct bytes to code (86 levels ≈ 6.4 bits, 52 ≈ 5.7, 18 ≈ 4.2). With a
//! budget the encoder takes the coarsest step within it. The runtime still sees an ordinary
//! 8-bit grid.
//!
//! Invariant: q 0 and 255 (a line's minimum and maximum) are on every grid, since every step
//! divides 255; a constant line quantizes exactly (scale 0, q 0); and a value decodes as
//! `offset + scale·q` whatever the step, so the decoder never needs to know it.

use super::MatrixCodec;

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
pub(super) fn u8_params(
    data: &[f32],
    rows: usize,
    cols: usize,
    per_column: bool,
) -> Vec<(f32, f32)> {
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
pub(super) fn u8_value(
    params: &[(f32, f32)],
    per_column: bool,
    cols: usize,
    k: usize,
    q: u8,
) -> f32 {
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
    // Each value's round trip as `round_trip_step` makes it, summed in row-major order, without
    // the round-tripped copy (and, for 8-bit codecs, without a division per value to find its
    // line).
    let (mut diff, mut norm) = (0.0f64, 0.0f64);
    let mut add = |a: f32, b: f32| {
        let d = b as f64 - a as f64;
        diff += d * d;
        norm += (a as f64) * (a as f64);
    };
    match codec {
        MatrixCodec::F32 => data.iter().for_each(|&a| add(a, a)),
        MatrixCodec::F16 => data
            .iter()
            .for_each(|&a| add(a, half::f16::from_f32(a).to_f32())),
        _ => {
            let per_column = codec.per_column();
            let params = u8_params(data, rows, cols, per_column);
            return u8_error(data, rows, cols, per_column, &params, step);
        }
    }
    relative_error(diff, norm)
}

/// [`codec_error_step`] of an 8-bit codec whose per-line `params` ([`u8_line_params`] of
/// each line, as [`quantize_matrix`] makes them) are given, so that trying several steps finds
/// them once.
pub(super) fn u8_error(
    data: &[f32],
    rows: usize,
    cols: usize,
    per_column: bool,
    params: &[(f32, f32)],
    step: u8,
) -> f64 {
    let (mut diff, mut norm) = (0.0f64, 0.0f64);
    for i in 0..rows {
        for j in 0..cols {
            let (offset, scale) = params[if per_column { j } else { i }];
            let a = data[i * cols + j];
            let q = quantize_u8(a, offset, scale, step);
            let d = (offset + scale * q as f32) as f64 - a as f64;
            diff += d * d;
            norm += (a as f64) * (a as f64);
        }
    }
    relative_error(diff, norm)
}

/// `sqrt(diff / norm)`, infinite when the difference is not finite or the matrix is zero and
/// the difference is not.
fn relative_error(diff: f64, norm: f64) -> f64 {
    if !diff.is_finite() {
        return f64::INFINITY;
    }
    if norm == 0.0 {
        return if diff == 0.0 { 0.0 } else { f64::INFINITY };
    }
    (diff / norm).sqrt()
}

/// The line-wise `(offset, scale)` pairs and the row-major q of a matrix on an 8-bit grid.
pub(super) fn quantize_matrix(
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
