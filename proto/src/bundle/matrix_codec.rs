//! One operator [`Matrix`] on the wire: [`MatrixEncoder`] picks each matrix's codec by the
//! [`EncodeOptions`] (the transport section under its own policy) and tallies what it chose into
//! the [`EncodeReport`]; reading decodes any codec to f32 and refuses values that are not finite.
//!
//! Invariant: an 8-bit matrix is written plain or predicted, whichever is smaller, and both decode
//! to the same values (see [`crate::codec`]); the report counts both under one codec name.

use crate::codec::{
    choose_encoding, read_matrix, u8_step_name, write_matrix_smallest, CodecPolicy,
};
use crate::wire::{Reader, WireError, Writer};

use super::{BundleError, EncodeOptions, EncodeReport, Matrix};

impl Matrix {
    pub(super) fn write(&self, w: &mut Writer, enc: &mut MatrixEncoder) {
        enc.write(w, self);
    }
    pub(super) fn read(r: &mut Reader, what: &str) -> Result<Matrix, BundleError> {
        let (rows, cols, data, _codec) = read_matrix(r).map_err(|e| match e {
            WireError::Invalid(m) => BundleError::Invalid(format!("{what}: {m}")),
            e => BundleError::Wire(e),
        })?;
        if let Some(k) = data.iter().position(|x| !x.is_finite()) {
            return Err(BundleError::Invalid(format!(
                "{what}: value {k} is not finite"
            )));
        }
        Ok(Matrix { rows, cols, data })
    }
}

/// Picks each operator matrix's codec by the [`EncodeOptions`] and tallies what it chose.
pub(super) struct MatrixEncoder {
    /// The policy of the matrices being written now.
    policy: CodecPolicy,
    /// The policy of the transport section's matrices.
    transport_policy: CodecPolicy,
    pub(super) report: EncodeReport,
}

impl MatrixEncoder {
    pub(super) fn new(options: &EncodeOptions) -> MatrixEncoder {
        MatrixEncoder {
            policy: options.codec,
            transport_policy: options.transport_codec.unwrap_or(options.codec),
            report: EncodeReport::default(),
        }
    }

    /// Writes the transport section's matrices (inside `write`) under the transport policy.
    pub(super) fn with_transport_policy(&mut self, write: impl FnOnce(&mut MatrixEncoder)) {
        let operator_policy = std::mem::replace(&mut self.policy, self.transport_policy);
        write(self);
        self.policy = operator_policy;
    }

    fn write(&mut self, w: &mut Writer, m: &Matrix) {
        let (rows, cols) = (m.rows as usize, m.cols as usize);
        let (codec, step, error) = choose_encoding(&m.data, rows, cols, self.policy);
        // Lossless: an 8-bit matrix's q go plain or as prediction residuals, whichever is
        // smaller; both decode to the same values.
        let codec = write_matrix_smallest(w, &m.data, rows, cols, codec, step);
        let name = if codec.is_u8() {
            u8_step_name(step)
        } else {
            codec.name()
        };
        let usage = self.report.codecs.entry(name).or_default();
        usage.matrices += 1;
        usage.predicted += codec.is_predicted() as u64;
        usage.values += (rows * cols) as u64;
        usage.bytes += codec.value_bytes(rows, cols) as u64;
        self.report.max_codec_error = self.report.max_codec_error.max(error);
    }
}
