//! 8-bit lines and what every codec gives back: per line (a column or a row) an
//! `(offset, scale)` pair and bytes q with value = offset + scale·q, on a grid the encoder
//! picks ([`U8Grid`]); [`round_trip`], the values a matrix decodes to in a codec; and
//! [`codec_error`], the relative RMS error `‖Q(M) − M‖_F / ‖M‖_F` that adds.
//!
//! Two families of grids, neither visible to the decoder:
//! - **Coarser steps** ([`U8Grid::Step`]): every line uses only every `step`-th level of its 256
//!   (`step` in [`U8_STEPS`], a divisor of 255, so the line's maximum stays on the grid): q is a
//!   multiple of `step`, which gives zstd only `255/step + 1` distinct bytes to code (86 levels
//!   ≈ 6.4 bits, 52 ≈ 5.7, 18 ≈ 4.2). Each line keeps the same precision relative to its range.
//! - **A floor** ([`U8Grid::Floor`]): every line's step is its range over 255 or the floor,
//!   whichever is larger — one absolute step for every line not already coarser. A line spanning
//!   fewer than 255 floors takes fewer levels (q up to `round(range / floor)`, centred on its
//!   range). The rounding error of a step `Δ` is about `Δ²/12` per value and an entropy coder
//!   spends about `log2(range / Δ)` bits on it, so at a given Frobenius error a matrix costs
//!   the fewest bits when its lines share one step: the weak (narrow) lines of a truncated
//!   SVD's `U_k Σ_k` no longer get the strong ones' relative precision. Which matrices may
//!   take a floor is the writer's choice ([`super::CodecPolicy::BudgetFloored`]): the
//!   Frobenius error is only a proxy of what a matrix's error does to the light, and a floor
//!   moves the error onto the weak lines.
//!
//! With a budget the encoder takes the coarsest grid of its family within it
//! ([`super::choose_encoding`]). Invariant: the full grid (`Step(1)`, `Floor(0)`) puts a
//! line's minimum and maximum at q 0 and 255, and so does every coarser step; a constant line
//! quantizes exactly (scale 0, q 0); a value decodes as `offset + scale·q` whatever the grid.

use super::MatrixCodec;

/// How the encoder places an 8-bit matrix's levels (see the module doc); the bytes decode the
/// same whatever it is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum U8Grid {
    /// Every `step`-th of each line's 256 levels (`step` divides 255; 1: the full grid).
    Step(u8),
    /// Each line's step at least this absolute value (0: the full grid).
    Floor(f32),
}

impl U8Grid {
    /// Every line on all 256 levels of its range.
    pub const FULL: U8Grid = U8Grid::Step(1);
}

/// Steps of the coarser 8-bit grids (divisors of 255), coarsest first.
pub const U8_STEPS: [u8; 5] = [17, 15, 5, 3, 1];

/// Report name of the 8-bit codec on `grid`.
pub fn u8_grid_name(grid: U8Grid) -> &'static str {
    match grid {
        U8Grid::Step(17) => "u8 (16 levels)",
        U8Grid::Step(15) => "u8 (18 levels)",
        U8Grid::Step(5) => "u8 (52 levels)",
        U8Grid::Step(3) => "u8 (86 levels)",
        U8Grid::Floor(f) if f > 0.0 => "u8 (floored steps)",
        _ => "u8",
    }
}

/// One 8-bit line: value = `offset + scale·q`, q a multiple of `every`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Line {
    pub offset: f32,
    pub scale: f32,
    every: u8,
}

impl Line {
    fn quantize(&self, v: f32) -> u8 {
        if self.scale > 0.0 {
            let every = self.every.max(1) as f32;
            let q = ((v - self.offset) / (self.scale * every)).round() * every;
            q.clamp(0.0, 255.0) as u8
        } else {
            0
        }
    }

    fn value(&self, q: u8) -> f32 {
        self.offset + self.scale * q as f32
    }
}

/// The value range `(lo, hi)` of each line of a matrix (columns or rows); `(inf, -inf)` for a
/// line with no values.
pub(super) fn line_ranges(
    data: &[f32],
    rows: usize,
    cols: usize,
    per_column: bool,
) -> Vec<(f32, f32)> {
    let lines = if per_column { cols } else { rows };
    let mut r = vec![(f32::INFINITY, f32::NEG_INFINITY); lines];
    for i in 0..rows {
        for j in 0..cols {
            let v = data[i * cols + j];
            let l = &mut r[if per_column { j } else { i }];
            l.0 = l.0.min(v);
            l.1 = l.1.max(v);
        }
    }
    r
}

/// The 8-bit line for values in `[lo, hi]` on `grid`.
pub(super) fn line_on((lo, hi): (f32, f32), grid: U8Grid) -> Line {
    let line = |offset, scale, every| Line {
        offset,
        scale,
        every,
    };
    if !lo.is_finite() {
        return line(0.0, 0.0, 1);
    }
    if hi.is_nan() || hi <= lo {
        return line(lo, 0.0, 1);
    }
    let full = (hi - lo) / 255.0;
    match grid {
        U8Grid::Step(step) => line(lo, full, step),
        U8Grid::Floor(floor) if floor > full => {
            let steps = ((hi - lo) / floor).round();
            line(lo + 0.5 * ((hi - lo) - steps * floor), floor, 1)
        }
        U8Grid::Floor(_) => line(lo, full, 1),
    }
}

/// The lines of an 8-bit matrix on `grid`; lines are columns or rows.
pub(super) fn u8_lines(
    data: &[f32],
    rows: usize,
    cols: usize,
    per_column: bool,
    grid: U8Grid,
) -> Vec<Line> {
    line_ranges(data, rows, cols, per_column)
        .into_iter()
        .map(|r| line_on(r, grid))
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
    round_trip_grid(data, rows, cols, codec, U8Grid::FULL)
}

/// [`round_trip`] with an 8-bit `grid` (ignored by the other codecs).
pub fn round_trip_grid(
    data: &[f32],
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    grid: U8Grid,
) -> Vec<f32> {
    match codec {
        MatrixCodec::F32 => data.to_vec(),
        MatrixCodec::F16 => data
            .iter()
            .map(|v| half::f16::from_f32(*v).to_f32())
            .collect(),
        _ => {
            let per_column = codec.per_column();
            let (params, q) = quantize_matrix(data, rows, cols, per_column, grid);
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
    codec_error_grid(data, rows, cols, codec, U8Grid::FULL)
}

/// [`codec_error`] with an 8-bit `grid`.
pub fn codec_error_grid(
    data: &[f32],
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    grid: U8Grid,
) -> f64 {
    // Each value's round trip as `round_trip_grid` makes it, summed in row-major order, without
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
            let lines = u8_lines(data, rows, cols, per_column, grid);
            return u8_error(data, rows, cols, per_column, &lines);
        }
    }
    relative_error(diff, norm)
}

/// [`codec_error_grid`] of an 8-bit codec whose `lines` ([`line_on`] of each line's range, as
/// [`quantize_matrix`] makes them) are given, so that trying several grids finds the lines'
/// ranges once.
pub(super) fn u8_error(
    data: &[f32],
    rows: usize,
    cols: usize,
    per_column: bool,
    lines: &[Line],
) -> f64 {
    let (mut diff, mut norm) = (0.0f64, 0.0f64);
    for i in 0..rows {
        for j in 0..cols {
            let line = lines[if per_column { j } else { i }];
            let a = data[i * cols + j];
            let d = line.value(line.quantize(a)) as f64 - a as f64;
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

/// The line-wise `(offset, scale)` pairs and the row-major q of a matrix on an 8-bit `grid`.
pub(super) fn quantize_matrix(
    data: &[f32],
    rows: usize,
    cols: usize,
    per_column: bool,
    grid: U8Grid,
) -> (Vec<(f32, f32)>, Vec<u8>) {
    let lines = u8_lines(data, rows, cols, per_column, grid);
    let mut q = Vec::with_capacity(rows * cols);
    for i in 0..rows {
        for j in 0..cols {
            q.push(lines[if per_column { j } else { i }].quantize(data[i * cols + j]));
        }
    }
    (lines.iter().map(|l| (l.offset, l.scale)).collect(), q)
}
