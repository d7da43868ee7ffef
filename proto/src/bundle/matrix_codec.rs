//! One operator [`Matrix`] on the wire: [`MatrixEncoder`] picks each matrix's codec by the
//! [`EncodeOptions`] (the transport section under its own policy) and tallies what it chose into
//! the [`EncodeReport`]; reading decodes any codec to f32 and refuses values that are not finite.
//!
//! The writer may list every matrix first and encode them on several threads
//! ([`MatrixEncoder::listing`], [`MatrixEncoder::encode_listed`]), then write the sections again
//! taking the encodings in order.
//!
//! Invariants: an 8-bit matrix is written plain or predicted, whichever is smaller, and both
//! decode to the same values (see [`crate::codec`]); the report counts both under one codec
//! name. A matrix's encoding is a pure function of it and its policy, so the bytes and the
//! report do not depend on the thread count.

use crate::codec::{
    choose_encoding, read_matrix, u8_grid_name, write_matrix_smallest, CodecPolicy, MatrixCodec,
    U8Grid,
};
use crate::wire::{Reader, WireError, Writer};
use crate::work_queue::map_in_order;

use super::{BundleError, EncodeOptions, EncodeReport, Matrix};

impl Matrix {
    pub(super) fn write<'a>(&'a self, w: &mut Writer, enc: &mut MatrixEncoder<'a>) {
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

/// One matrix as the writer encodes it: its bytes on the wire, the codec and 8-bit grid it
/// chose and the error that adds (what the report counts of it follows from these and the
/// matrix's size). The bytes are shared, so a memo keeps an encoding without copying it.
#[derive(Clone, Debug, PartialEq)]
pub struct MatrixEncoding {
    pub bytes: std::sync::Arc<Vec<u8>>,
    pub codec: MatrixCodec,
    pub grid: U8Grid,
    pub error: f64,
}

/// Encodings a writer made before, handed back so that an unchanged matrix is not encoded
/// again, nor an unchanged section compressed again (a rebake after a clutter edit writes the
/// same transport and shapes).
///
/// Invariant the implementation keeps: it hands back an earlier encoding only for a matrix
/// with the same size and value bits under the same policy, made by a writer of this same
/// code; the bytes then are what `encode` would give.
pub trait EncodingMemo: Sync {
    /// The encoding of `m`, the `index`-th matrix of this write (file order), under `policy`:
    /// one kept from an earlier write, or `encode()`'s; either way kept for the next write.
    /// Called from the writer's threads, each matrix once.
    fn encoding(
        &self,
        index: usize,
        m: &Matrix,
        policy: CodecPolicy,
        encode: &dyn Fn() -> MatrixEncoding,
    ) -> MatrixEncoding;

    /// The stored payload of the section of `kind` whose raw payload is `raw`, at zstd `level`
    /// ([`crate::container::compress_section`]'s, which `compress` computes): one kept from an
    /// earlier write of the same bytes at the same level, or `compress()`'s; either way kept
    /// for the next write. Called from the writer's threads, each section once. Without an
    /// override, `compress()`.
    fn section(
        &self,
        kind: u32,
        raw: &[u8],
        level: i32,
        compress: &dyn Fn() -> Option<Vec<u8>>,
    ) -> Option<Vec<u8>> {
        let _ = (kind, raw, level);
        compress()
    }
}

/// Encodes one matrix under `policy`: a pure function of the matrix and the policy.
fn encode_matrix(m: &Matrix, policy: CodecPolicy) -> MatrixEncoding {
    let (rows, cols) = (m.rows as usize, m.cols as usize);
    let (codec, grid, error) = choose_encoding(&m.data, rows, cols, policy);
    // Lossless: an 8-bit matrix's q go plain or as prediction residuals, whichever is
    // smaller; both decode to the same values.
    let mut w = Writer::new();
    let codec = write_matrix_smallest(&mut w, &m.data, rows, cols, codec, grid);
    MatrixEncoding {
        bytes: std::sync::Arc::new(w.bytes),
        codec,
        grid,
        error,
    }
}

/// How [`MatrixEncoder::write`] works: encoding each matrix as it comes, listing the matrices
/// (a first pass over the sections, writing nothing that is kept), or writing the encodings a
/// parallel pass made from that list, in the same order.
enum Mode<'a> {
    Direct,
    Collect(Vec<(&'a Matrix, CodecPolicy)>),
    Replay(std::vec::IntoIter<MatrixEncoding>),
}

/// Picks each operator matrix's codec by the [`EncodeOptions`] and tallies what it chose.
///
/// Invariant: the bytes and the report are the same in every mode: a matrix's encoding is a
/// pure function of it and its policy, and the report is tallied in write order.
pub(super) struct MatrixEncoder<'a> {
    /// The policy of the matrices being written now.
    policy: CodecPolicy,
    /// The policy of the transport section's matrices.
    transport_policy: CodecPolicy,
    mode: Mode<'a>,
    pub(super) report: EncodeReport,
}

impl<'a> MatrixEncoder<'a> {
    pub(super) fn new(options: &EncodeOptions) -> MatrixEncoder<'a> {
        MatrixEncoder {
            policy: options.codec,
            transport_policy: options.transport_codec.unwrap_or(options.codec),
            mode: Mode::Direct,
            report: EncodeReport::default(),
        }
    }

    /// An encoder that lists the matrices written through it ([`MatrixEncoder::encode_listed`]).
    pub(super) fn listing(options: &EncodeOptions) -> MatrixEncoder<'a> {
        MatrixEncoder {
            mode: Mode::Collect(Vec::new()),
            ..MatrixEncoder::new(options)
        }
    }

    /// Whether this encoder only lists matrices: the bytes written through it are dropped, so
    /// a writer may skip what holds no matrix (the exact gather, whose modelled form is the
    /// costliest such part to code).
    pub(super) fn is_listing(&self) -> bool {
        matches!(self.mode, Mode::Collect(_))
    }

    /// Encodes the listed matrices on `threads` threads (each the same bytes as alone) and
    /// returns an encoder that writes them, in the listed order, when the same sections are
    /// written through it.
    pub(super) fn encode_listed(
        self,
        options: &EncodeOptions,
        threads: usize,
        memo: Option<&dyn EncodingMemo>,
    ) -> MatrixEncoder<'a> {
        let Mode::Collect(jobs) = self.mode else {
            panic!("encode_listed on an encoder that did not list");
        };
        let done = map_in_order(&jobs, threads, |k, &(m, policy)| {
            let encode = || encode_matrix(m, policy);
            match memo {
                Some(memo) => memo.encoding(k, m, policy, &encode),
                None => encode(),
            }
        });
        MatrixEncoder {
            mode: Mode::Replay(done.into_iter()),
            ..MatrixEncoder::new(options)
        }
    }

    /// Writes the transport section's matrices (inside `write`) under the transport policy.
    pub(super) fn with_transport_policy(&mut self, write: impl FnOnce(&mut MatrixEncoder<'a>)) {
        let operator_policy = std::mem::replace(&mut self.policy, self.transport_policy);
        write(self);
        self.policy = operator_policy;
    }

    /// Writes (inside `write`) under the current policy with its error budget scaled by
    /// `factor` (a fixed codec stays as it is).
    pub(super) fn with_budget_scaled(
        &mut self,
        factor: f64,
        write: impl FnOnce(&mut MatrixEncoder<'a>),
    ) {
        let policy = self.policy;
        self.policy = match policy {
            CodecPolicy::Budget(b) => CodecPolicy::Budget(b * factor),
            CodecPolicy::BudgetFloored(b) => CodecPolicy::BudgetFloored(b * factor),
            fixed => fixed,
        };
        write(self);
        self.policy = policy;
    }

    /// Writes (inside `write`) with the current budget's 8-bit lines under one floor
    /// ([`CodecPolicy::BudgetFloored`]; a fixed codec stays as it is).
    pub(super) fn with_floored_steps(&mut self, write: impl FnOnce(&mut MatrixEncoder<'a>)) {
        let policy = self.policy;
        if let CodecPolicy::Budget(b) = policy {
            self.policy = CodecPolicy::BudgetFloored(b);
        }
        write(self);
        self.policy = policy;
    }

    fn write(&mut self, w: &mut Writer, m: &'a Matrix) {
        let e = match &mut self.mode {
            Mode::Direct => encode_matrix(m, self.policy),
            Mode::Collect(jobs) => {
                jobs.push((m, self.policy));
                return;
            }
            Mode::Replay(done) => done.next().expect("the sections list the same matrices"),
        };
        w.bytes.extend_from_slice(&e.bytes);
        let (rows, cols) = (m.rows as usize, m.cols as usize);
        let name = if e.codec.is_u8() {
            u8_grid_name(e.grid)
        } else {
            e.codec.name()
        };
        let usage = self.report.codecs.entry(name).or_default();
        usage.matrices += 1;
        usage.predicted += e.codec.is_predicted() as u64;
        usage.values += (rows * cols) as u64;
        usage.bytes += e.codec.value_bytes(rows, cols) as u64;
        self.report.max_codec_error = self.report.max_codec_error.max(e.error);
    }
}
