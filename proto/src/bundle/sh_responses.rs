//! SH incident-radiance responses for normal-mapped surfaces (DRT §5, "vector responses";
//! bundle section 10 `sh`, minor version 2).
//!
//! Per lit texel x and RGB channel, the incident radiance `L(x, ω)` projected on the order-2 SH
//! basis of [`crate::sh`] (world frame, y up, 9 coefficients, `L_lm = ∫ L Y_lm dω` over the
//! texel's geometric hemisphere; directions below it see the surface itself, so they carry 0),
//! as a linear map from the coefficient vectors the scalar runtime already computes: a block's
//! `b` or a clutter object's `c`.
//!
//! One [`ShEntry`] per (receiving object, source), stored factored as `M ≈ Y · Z`:
//! `sh[texels[i]][lm] += Y.row(9·i + lm) · (Z · coefficients(source))` per channel, with
//! `Y` (9·texels × k) and `Z` (k × r or m), k from the bake's tolerance. Incident radiance, not
//! outgoing: no albedo inside (the client shades with `ρ/π · E(n')`, `E` the SH irradiance at
//! the perturbed normal).
//!
//! Invariant: after [`validate`] every entry's texels are ascending, unique and inside the
//! layout, `Y` is `9·texels × k`, `Z` is `k × width(source)` with `k ≤ width(source)` (so a
//! runtime's scratch is bounded by real operator data), and every source exists.

use super::delta_entries::{read_source, write_source};
use super::matrix_codec::MatrixEncoder;
use super::{BundleError, DeltaSource, Matrix};
use crate::sh::SH_COEFFS;
use crate::wire::{Reader, Writer};

/// The `sh` section.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ShResponses {
    pub entries: Vec<ShEntry>,
}

/// One receiving object's SH response to one source, factored (see the module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct ShEntry {
    /// Global texel indices, strictly ascending.
    pub texels: Vec<u32>,
    pub source: DeltaSource,
    /// 9·texels × k; row `9·i + lm` is coefficient `lm` of `texels[i]`.
    pub y: Matrix,
    /// k × (the source's r or m).
    pub z: Matrix,
}

impl ShResponses {
    /// The widest `Z` output (k) over entries: per-channel scratch a runtime needs.
    pub fn max_rank(&self) -> usize {
        self.entries
            .iter()
            .map(|e| e.z.rows as usize)
            .max()
            .unwrap_or(0)
    }
}

pub(super) fn write_sh<'a>(w: &mut Writer, sh: &'a ShResponses, enc: &mut MatrixEncoder<'a>) {
    w.u32(sh.entries.len() as u32);
    for e in &sh.entries {
        w.u32s(&e.texels);
        // Direct-light sources are never baked here; validation refuses them.
        write_source(w, e.source, 0);
        e.y.write(w, enc);
        e.z.write(w, enc);
    }
}

pub(super) fn read_sh(r: &mut Reader) -> Result<ShResponses, BundleError> {
    let n = r.u32()? as usize;
    let mut entries = Vec::with_capacity(n.min(r.remaining() / 32));
    for _ in 0..n {
        let texels = r.u32s()?;
        let (source, flags) = read_source(r, "sh: entry")?;
        if flags != 0 {
            return Err(BundleError::Invalid(format!(
                "sh: entry has unknown source flags {flags:#x}"
            )));
        }
        entries.push(ShEntry {
            texels,
            source,
            y: Matrix::read(r, "sh entry Y")?,
            z: Matrix::read(r, "sh entry Z")?,
        });
    }
    Ok(ShResponses { entries })
}

/// Checks sizes and indices. `width(source)` is the source's coefficient count (None: the
/// source does not exist).
pub(super) fn validate(
    sh: &ShResponses,
    n_texels: u64,
    width: &dyn Fn(DeltaSource) -> Option<u32>,
) -> Result<(), BundleError> {
    let bad = |m: String| Err(BundleError::Invalid(m));
    for (k, e) in sh.entries.iter().enumerate() {
        let Some(cols) = width(e.source) else {
            return bad(format!("sh: entry {k} names a missing source"));
        };
        if e.y.data.len() as u64 != e.y.rows as u64 * e.y.cols as u64
            || e.z.data.len() as u64 != e.z.rows as u64 * e.z.cols as u64
        {
            return bad(format!("sh: entry {k} holds the wrong number of values"));
        }
        if e.y.rows as u64 != SH_COEFFS as u64 * e.texels.len() as u64
            || e.y.cols != e.z.rows
            || e.z.cols != cols
            || e.z.rows > cols
        {
            return bad(format!(
                "sh: entry {k} has the wrong size (y {}×{}, z {}×{}, {} texels, source width {cols})",
                e.y.rows,
                e.y.cols,
                e.z.rows,
                e.z.cols,
                e.texels.len()
            ));
        }
        if e.texels.iter().any(|t| *t as u64 >= n_texels)
            || e.texels.windows(2).any(|w| w[1] <= w[0])
        {
            return bad(format!(
                "sh: entry {k} texels out of range or not ascending"
            ));
        }
    }
    Ok(())
}
