//! Which codec a [`CodecPolicy`] gives a matrix: a fixed codec (any 8-bit one meaning 8-bit on
//! the matrix's shorter side), or under a budget the smallest codec whose [`codec_error`] fits:
//! the coarsest 8-bit grid of the policy's family within it (coarser steps for
//! [`CodecPolicy::Budget`], a floor for [`CodecPolicy::BudgetFloored`]: [`coarsest_floor`]) with
//! pairs on the shorter side, else on the longer side (when that is smaller than f16), else
//! f16, else f32.
//!
//! Invariant: the choice is a pure function of the values and the policy (deterministic across
//! runs and machines: floors are exact f32 products, no `powf`), and the error
//! [`choose_encoding`] reports is the one its codec and grid add.

use super::quantize::{codec_error, line_on, line_ranges, u8_error, U8Grid, U8_STEPS};
use super::{CodecPolicy, MatrixCodec};

/// Floors tried per halving: a rung is `2^(-1/4)` (19%) finer than the one before.
const RUNGS_PER_OCTAVE: usize = 4;
/// `2^(-i/4)` for i in 0..4 (a rung is one of these times a power of two).
const RUNG: [f32; RUNGS_PER_OCTAVE] = [1.0, 0.840_896_4, 0.707_106_77, 0.594_603_56];

/// The codec `policy` gives a matrix, with the error it adds (full 8-bit grid).
pub fn choose_codec(
    data: &[f32],
    rows: usize,
    cols: usize,
    policy: CodecPolicy,
) -> (MatrixCodec, f64) {
    let (codec, grid, error) = choose_encoding(data, rows, cols, policy);
    if grid == U8Grid::FULL {
        return (codec, error);
    }
    (codec, codec_error(data, rows, cols, codec))
}

/// The codec and 8-bit grid `policy` gives a matrix, with the error they add. A budget takes
/// the coarsest 8-bit grid of its family within it (shorter side, then longer side while
/// smaller than f16), else f16, else f32; a fixed codec uses the full grid.
pub fn choose_encoding(
    data: &[f32],
    rows: usize,
    cols: usize,
    policy: CodecPolicy,
) -> (MatrixCodec, U8Grid, f64) {
    let (codec, error) = match policy {
        CodecPolicy::Fixed(codec) if codec.is_u8() => {
            let codec = MatrixCodec::u8_for(rows, cols);
            (codec, codec_error(data, rows, cols, codec))
        }
        CodecPolicy::Fixed(codec) => (codec, codec_error(data, rows, cols, codec)),
        CodecPolicy::Budget(budget) | CodecPolicy::BudgetFloored(budget) => {
            let floored = matches!(policy, CodecPolicy::BudgetFloored(_));
            // The shorter side first (fewest pairs); the longer side only where it is still
            // smaller than f16. A matrix whose lines each span sources of very different
            // strength (the transport's `Z`, k × Σ r_A: a row runs across every source block)
            // keeps no precision for the weak ones in a per-row range, but fits the budget with
            // a pair per column.
            let shorter = MatrixCodec::u8_for(rows, cols);
            let f16_bytes = MatrixCodec::F16.value_bytes(rows, cols);
            for u8_codec in [shorter, shorter.other_side()] {
                if u8_codec != shorter && u8_codec.value_bytes(rows, cols) >= f16_bytes {
                    continue;
                }
                let errors = GridErrors::new(data, rows, cols, u8_codec);
                let fit = if floored {
                    floor_within(&errors, budget)
                } else {
                    coarsest_step(&errors, budget)
                };
                if let Some((grid, e)) = fit {
                    return (u8_codec, grid, e);
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
    (codec, U8Grid::FULL, error)
}

/// The error one matrix's 8-bit lines take on any grid, its lines' ranges found once.
struct GridErrors<'a> {
    data: &'a [f32],
    rows: usize,
    cols: usize,
    per_column: bool,
    ranges: Vec<(f32, f32)>,
}

impl<'a> GridErrors<'a> {
    fn new(data: &'a [f32], rows: usize, cols: usize, codec: MatrixCodec) -> GridErrors<'a> {
        let per_column = codec.per_column();
        GridErrors {
            data,
            rows,
            cols,
            per_column,
            ranges: line_ranges(data, rows, cols, per_column),
        }
    }

    fn at(&self, grid: U8Grid) -> f64 {
        let lines: Vec<_> = self.ranges.iter().map(|&r| line_on(r, grid)).collect();
        u8_error(self.data, self.rows, self.cols, self.per_column, &lines)
    }
}

/// The coarsest of [`U8_STEPS`] within `budget`, with its error; None when not even the full
/// grid fits.
fn coarsest_step(errors: &GridErrors, budget: f64) -> Option<(U8Grid, f64)> {
    U8_STEPS.into_iter().find_map(|step| {
        let e = errors.at(U8Grid::Step(step));
        (e <= budget).then_some((U8Grid::Step(step), e))
    })
}

/// The coarsest floor of the 8-bit `codec` whose error is within `budget`, with that error;
/// None when not even the full grid (floor 0) fits.
///
/// The floors tried are the rungs `widest · 2^(-i/4)`, from the widest line's whole range
/// (every line then takes at most two levels) down to the narrowest line's full-grid step
/// (below which every line is on its full grid, floor 0). The error grows with the floor, up
/// to rounding, so the search bisects the rungs; what it returns was measured within the budget.
pub fn coarsest_floor(
    data: &[f32],
    rows: usize,
    cols: usize,
    codec: MatrixCodec,
    budget: f64,
) -> Option<(U8Grid, f64)> {
    floor_within(&GridErrors::new(data, rows, cols, codec), budget)
}

/// [`coarsest_floor`] of the matrix `errors` measures.
fn floor_within(errors: &GridErrors, budget: f64) -> Option<(U8Grid, f64)> {
    let error = |floor: f32| errors.at(U8Grid::Floor(floor));
    let ranges = &errors.ranges;
    let full = error(0.0);
    if full.is_nan() || full > budget {
        return None;
    }
    let spans = ranges
        .iter()
        .filter(|(lo, hi)| hi > lo)
        .map(|(lo, hi)| hi - lo);
    let (widest, narrowest) = spans.fold((0.0f32, f32::INFINITY), |(w, n), s| (w.max(s), n.min(s)));
    if !(widest > 0.0 && widest.is_finite()) {
        return Some((U8Grid::Floor(0.0), full));
    }
    let rung = |i: usize| {
        let mut r = widest * RUNG[i % RUNGS_PER_OCTAVE];
        for _ in 0..i / RUNGS_PER_OCTAVE {
            r *= 0.5;
        }
        r
    };
    // Rungs 0..n; from rung n on every line is on its full grid, which fits.
    let finest = narrowest / 255.0;
    let mut n = 0;
    while n < 64 * RUNGS_PER_OCTAVE && rung(n) > finest {
        n += 1;
    }
    let (mut lo, mut hi) = (0, n);
    let mut best = (0.0, full);
    while lo < hi {
        let mid = (lo + hi) / 2;
        let e = error(rung(mid));
        if e <= budget {
            best = (rung(mid), e);
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    Some((U8Grid::Floor(best.0), best.1))
}
