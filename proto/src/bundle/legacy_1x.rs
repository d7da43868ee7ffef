//! What only 1.x bundles hold, read so that a 2.x reader still decodes them (no 2.x writer
//! writes any of it): section kind 3 blocks (records without a box symmetry; 2.x writes kind 14,
//! `symmetric_blocks`) and form 1 of the exact gather (CSR as in memory; 2.x writes form 2,
//! `gather_encoding`). The DRT, probe and other section kinds of 1.x are still what 2.x writes
//! and are read by `read`; codec tags 0–3 by [`crate::codec`].
//!
//! Invariant: read-only and isolated: nothing here is called by the writer, and a 1.x payload
//! decodes to the same [`super::Bundle`] fields a 2.x one does (a kind 3 block has no symmetry).

use crate::wire::Reader;

use super::{BlockOps, BundleError, TexelGather};

/// Reads section kind 3: `n:u32 × (id:str shape:u32 texel_offset:u32)`.
pub(super) fn read_blocks(r: &mut Reader) -> Result<Vec<BlockOps>, BundleError> {
    let n = r.u32()? as usize;
    let mut out = Vec::with_capacity(n.min(r.remaining() / 12));
    for _ in 0..n {
        out.push(BlockOps {
            id: r.str()?,
            shape: r.u32()?,
            texel_offset: r.u32()?,
            symmetry: None,
        });
    }
    Ok(out)
}

/// Reads form 1 of the exact gather (after its flag byte): `rows:u32s row_start:u32s cols:u32s
/// values:f32s`, CSR as it is in memory.
pub(super) fn read_gather_csr(r: &mut Reader) -> Result<TexelGather, BundleError> {
    Ok(TexelGather {
        rows: r.u32s()?,
        row_start: r.u32s()?,
        cols: r.u32s()?,
        values: r.f32s()?,
        tiles: Default::default(),
    })
}
