//! Reading one matrix, in any codec, back to row-major f32 ([`read_matrix`]).
//!
//! Invariant: never panics and never allocates more than the bytes it was given can fill: the
//! size a matrix needs is checked against the remaining input before any allocation.

use crate::wire::{Reader, WireError};

use super::predict::{line_len, undo_residuals};
use super::quantize::u8_value;
use super::MatrixCodec;

/// A decoded matrix: `(rows, cols, row-major values, codec)`. Values may be non-finite only if
/// the bytes say so; callers validate.
pub type DecodedMatrix = (u32, u32, Vec<f32>, MatrixCodec);

/// Reads what [`write_matrix`](super::write_matrix) wrote.
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
