//! Delta entries on the wire: the [`DeltaEntry`] list the DRT and probe sections share, and the
//! encoding of a [`DeltaSource`] (kind byte with flag bits, then its index or range) that the
//! `sh` section reuses.
//!
//! The writer may give each entry's own matrix one floor on its 8-bit steps ([`FlooredLeft`]);
//! the bytes read the same either way.
//!
//! Invariant: bit 7 of an entry's source kind byte says a `mix` matrix follows; a reader refuses
//! any other flag bit and any unknown source kind.

use crate::wire::{Reader, Writer};

use super::index_lists::{read_index_list, write_index_list, IndexLists};
use super::matrix_codec::MatrixEncoder;
use super::{BundleError, DeltaEntry, DeltaSource, Matrix};

/// Whether [`write_entries`] gives each entry's own matrix (a dense delta, or the left factor
/// `U_k Σ_k` of a low-rank one) one floor on its 8-bit lines' steps
/// ([`crate::codec::CodecPolicy::BudgetFloored`]); a `mix` (`V_kᵀ`, rows of one size) never.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum FlooredLeft {
    Yes,
    No,
}

/// The entries, each entry's matrix under `floored`'s policy.
pub(super) fn write_entries<'a>(
    w: &mut Writer,
    entries: &'a [DeltaEntry],
    enc: &mut MatrixEncoder<'a>,
    floored: FlooredLeft,
    lists: IndexLists,
) {
    w.u32(entries.len() as u32);
    for e in entries {
        write_index_list(w, &e.rows, lists);
        // Bit 7 of the source kind: a `mix` matrix follows the entry's matrix.
        write_source(w, e.source, if e.mix.is_some() { 0x80 } else { 0 });
        match floored {
            FlooredLeft::Yes => enc.with_floored_steps(|enc| e.matrix.write(w, enc)),
            FlooredLeft::No => e.matrix.write(w, enc),
        }
        if let Some(mix) = &e.mix {
            mix.write(w, enc);
        }
    }
}

/// Writes a delta source: its kind byte (0 block, 1 clutter, 2 direct-light range) with `flags`
/// or-ed into bits 4–7, then its index or `first, count`.
pub(crate) fn write_source(w: &mut Writer, source: DeltaSource, flags: u8) {
    match source {
        DeltaSource::Block(b) => {
            w.u8(flags);
            w.u32(b);
        }
        DeltaSource::Clutter(c) => {
            w.u8(1 | flags);
            w.u32(c);
        }
        DeltaSource::Direct { first, count } => {
            w.u8(2 | flags);
            w.u32(first);
            w.u32(count);
        }
    }
}

/// Reads what [`write_source`] wrote: the source and the kind byte's flag bits.
pub(crate) fn read_source(r: &mut Reader, what: &str) -> Result<(DeltaSource, u8), BundleError> {
    let kind = r.u8()?;
    let source = match kind & 0x0f {
        0 => DeltaSource::Block(r.u32()?),
        1 => DeltaSource::Clutter(r.u32()?),
        2 => DeltaSource::Direct {
            first: r.u32()?,
            count: r.u32()?,
        },
        k => {
            return Err(BundleError::Invalid(format!(
                "{what}: unknown source kind {k}"
            )))
        }
    };
    Ok((source, kind & 0xf0))
}

pub(super) fn read_entries(
    r: &mut Reader,
    lists: IndexLists,
) -> Result<Vec<DeltaEntry>, BundleError> {
    let n_entries = r.u32()? as usize;
    let mut entries = Vec::with_capacity(n_entries.min(r.remaining() / 24));
    for _ in 0..n_entries {
        let rows = read_index_list(r, lists)?;
        let (source, flags) = read_source(r, "delta entry")?;
        if flags & !0x80 != 0 {
            return Err(BundleError::Invalid(format!(
                "delta entry: unknown source flags {flags:#x}"
            )));
        }
        let matrix = Matrix::read(r, "delta entry")?;
        let mix = if flags & 0x80 != 0 {
            Some(Matrix::read(r, "delta entry mix")?)
        } else {
            None
        };
        entries.push(DeltaEntry {
            rows,
            source,
            matrix,
            mix,
        });
    }
    Ok(entries)
}
