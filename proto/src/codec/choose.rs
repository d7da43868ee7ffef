//! Which codec a [`CodecPolicy`] gives a matrix: a fixed codec (any 8-bit one meaning 8-bit on
//! the matrix's shorter side), or under a budget the smallest codec whose [`codec_error`] fits:
//! the coarsest 8-bit grid within it with pairs on the shorter side, else on the longer side
//! (when that is smaller than f16), else f16, else f32.
//!
//! Invariant: the choice is a pure function of the values and the policy (deterministic across
//! runs and machines), and the error [`choose_encoding`] reports is the one its codec and step
//! add.

use super::quantize::{codec_error, u8_error, u8_params, U8_STEPS};
use super::{CodecPolicy, MatrixCodec};

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
/// takes the coarsest 8-bit grid within it (shorter side, then longer side while smaller than
/// f16), else f16, else f32; a fixed codec uses the full grid.
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
                let per_column = u8_codec.per_column();
                let params = u8_params(data, rows, cols, per_column);
                for step in U8_STEPS {
                    let e = u8_error(data, rows, cols, per_column, &params, step);
                    if e <= budget {
                        return (u8_codec, step, e);
                    }
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
