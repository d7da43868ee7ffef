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
//!
//! Values are always row-major. Decoding returns f32 whatever the codec, and never allocates
//! more than the bytes it was given can fill (sizes are checked against the remaining input
//! before any allocation).
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
}

impl MatrixCodec {
    fn tag(self) -> u8 {
        match self {
            MatrixCodec::F32 => 0,
            MatrixCodec::F16 => 1,
            MatrixCodec::U8Columns => 2,
            MatrixCodec::U8Rows => 3,
        }
    }

    fn from_tag(tag: u8) -> Option<MatrixCodec> {
        Some(match tag {
            0 => MatrixCodec::F32,
            1 => MatrixCodec::F16,
            2 => MatrixCodec::U8Columns,
            3 => MatrixCodec::U8Rows,
            _ => return None,
        })
    }

    /// Short name for reports (`f32`, `f16`, `u8`).
    pub fn name(self) -> &'static str {
        match self {
            MatrixCodec::F32 => "f32",
            MatrixCodec::F16 => "f16",
            MatrixCodec::U8Columns | MatrixCodec::U8Rows => "u8",
        }
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
        }
    }
}

/// Which codec the encoder uses for each matrix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CodecPolicy {
    /// Every matrix in one codec (`U8Columns`/`U8Rows` both mean "8-bit on the shorter side").
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
        MatrixCodec::U8Columns | MatrixCodec::U8Rows => {
            let per_column = codec == MatrixCodec::U8Columns;
            let params = u8_params(data, rows, cols, per_column);
            let mut out = Vec::with_capacity(data.len());
            for i in 0..rows {
                for j in 0..cols {
                    let (offset, scale) = params[if per_column { j } else { i }];
                    let q = quantize_u8(data[i * cols + j], offset, scale, step);
                    out.push(offset + scale * q as f32);
                }
            }
            out
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
        CodecPolicy::Fixed(MatrixCodec::U8Columns | MatrixCodec::U8Rows) => {
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

/// [`write_matrix`] on an 8-bit grid with `step` (the bytes decode like any 8-bit matrix).
pub fn write_matrix_step(
    w: &mut Writer,
    data: &[f32],
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    step: u8,
) {
    debug_assert_eq!(data.len(), rows * cols);
    w.u32(rows as u32);
    w.u32(cols as u32);
    w.u8(codec.tag());
    match codec {
        MatrixCodec::F32 => {
            for v in data {
                w.f32(*v);
            }
        }
        MatrixCodec::F16 => {
            for v in data {
                w.bytes
                    .extend_from_slice(&half::f16::from_f32(*v).to_bits().to_le_bytes());
            }
        }
        MatrixCodec::U8Columns | MatrixCodec::U8Rows => {
            let per_column = codec == MatrixCodec::U8Columns;
            let params = u8_params(data, rows, cols, per_column);
            for (offset, scale) in &params {
                w.f32(*offset);
                w.f32(*scale);
            }
            for i in 0..rows {
                for j in 0..cols {
                    let (offset, scale) = params[if per_column { j } else { i }];
                    w.u8(quantize_u8(data[i * cols + j], offset, scale, step));
                }
            }
        }
    }
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
        MatrixCodec::U8Columns | MatrixCodec::U8Rows => {
            let per_column = codec == MatrixCodec::U8Columns;
            let lines = if per_column { cols } else { rows } as usize;
            let mut params = Vec::with_capacity(lines);
            for _ in 0..lines {
                params.push((r.f32()?, r.f32()?));
            }
            let q = r.take(n)?;
            let cols = cols as usize;
            q.iter()
                .enumerate()
                .map(|(k, q)| {
                    let (offset, scale) = params[if per_column { k % cols } else { k / cols }];
                    offset + scale * *q as f32
                })
                .collect()
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
            tag in 0u8..4,
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
    }
}
