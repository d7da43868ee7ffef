//! Matrix codecs of the bundle: how one operator's values are stored on the wire.
//!
//! Every operator matrix is written as `rows u32, cols u32, codec u8` then its values:
//! - [`MatrixCodec::F32`]: `rows·cols` little-endian f32 (lossless);
//! - [`MatrixCodec::F16`]: `rows·cols` IEEE binary16 (about 3 significant digits);
//! - [`MatrixCodec::U8Columns`]: per column an `(offset f32, scale f32)` pair, then `rows·cols`
//!   bytes q, value = offset + scale·q; [`MatrixCodec::U8Rows`]: the same with one pair per row.
//!   The encoder puts the pairs on the shorter side, which for our operators is the side of the
//!   modes (U_b is texels × r: per column; T_d→b is r × texels: per row), so every mode has its
//!   own range; under a budget, on the longer side when only that fits it and is smaller than
//!   f16 (the compact transport's `Z`, whose columns belong to source blocks of very different
//!   strength).
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
//! How a matrix is predicted is in `predict`, the 8-bit grids and the error a codec adds
//! ([`codec_error`]) in `quantize`; [`choose_encoding`] picks the smallest codec within a budget.
//!
//! # Layout
//! This file holds the codecs ([`MatrixCodec`], its tags and sizes) and the policy that picks
//! one ([`CodecPolicy`]), and re-exports what the files beside it define, so every public path
//! is `codec::X`. One concept per file:
//! - `quantize`: 8-bit lines (`offset + scale·q`) on the full grid, a coarser one or with one
//!   floor on every line's step ([`U8Grid`]), the values any codec gives back ([`round_trip`])
//!   and the error it adds ([`codec_error`]).
//! - `predict`: the median predictor over the texel grid, its residuals, the predictor width
//!   ([`best_predictor_width`]) and whether the predicted form is the smaller.
//! - `choose`: the codec and 8-bit grid a [`CodecPolicy`] gives a matrix ([`choose_encoding`],
//!   [`coarsest_floor`]).
//! - `write`: a matrix on the wire in a given codec ([`write_matrix`]), or in the smaller of the
//!   plain and predicted 8-bit forms ([`write_matrix_smallest`], what the bundle writer calls).
//! - `read`: any codec back to f32 ([`read_matrix`]).
//! - `tests`: round trips, the wire format of the predicted forms, the budget's choices.

mod choose;
mod predict;
mod quantize;
mod read;
#[cfg(test)]
mod tests;
mod write;
pub use choose::{choose_codec, choose_encoding, coarsest_floor};
pub use predict::{best_predictor_width, PREDICTOR_WIDTHS};
pub use quantize::{
    codec_error, codec_error_grid, round_trip, round_trip_grid, u8_grid_name, U8Grid, U8_STEPS,
};
pub use read::{read_matrix, DecodedMatrix};
pub use write::{write_matrix, write_matrix_grid, write_matrix_predicted, write_matrix_smallest};

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
    /// The codec's tag on the wire (0–5).
    pub fn tag(self) -> u8 {
        match self {
            MatrixCodec::F32 => 0,
            MatrixCodec::F16 => 1,
            MatrixCodec::U8Columns => 2,
            MatrixCodec::U8Rows => 3,
            MatrixCodec::U8ColumnsPredicted => 4,
            MatrixCodec::U8RowsPredicted => 5,
        }
    }

    /// The codec of a wire tag; None for an unknown one.
    pub fn from_tag(tag: u8) -> Option<MatrixCodec> {
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

    /// The plain 8-bit codec with its pairs on the other side of an 8-bit codec's (rows ↔
    /// columns).
    fn other_side(self) -> MatrixCodec {
        if self.per_column() {
            MatrixCodec::U8Rows
        } else {
            MatrixCodec::U8Columns
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
    /// Per matrix, the smallest codec whose [`codec_error`] is at most this relative RMS error,
    /// 8-bit lines on their own range's grid or a coarser step of it ([`U8Grid::Step`]).
    Budget(f64),
    /// [`CodecPolicy::Budget`] with 8-bit lines under one floor on their step
    /// ([`U8Grid::Floor`]): for matrices whose weak lines matter to the light in proportion to
    /// their size (the writer's choice; see `quantize`).
    BudgetFloored(f64),
}
