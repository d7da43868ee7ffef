//! `eval --sh-out FILE`: the file of every texel's SH incident radiance
//! ([`crate::evaluate::sh::sh_incident`]).
//!
//! File: raw little-endian f32, layout texel order, 27 values per texel: channel-major R, G, B,
//! each the 9 coefficients of `lightfarm_proto::sh` (world frame, y up; incident radiance, no
//! albedo). Texels the bake left without rows (buried) are 0.

use std::path::Path;

use anyhow::Context;
use lightfarm_client::ShLight;

/// Writes `sh` in the file format above.
pub fn write_sh_file(path: &Path, sh: &ShLight) -> anyhow::Result<()> {
    let mut bytes = Vec::with_capacity(sh.coefficients.len() * 27 * 4);
    for texel in &sh.coefficients {
        for v in texel.iter().flatten() {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::write(path, bytes).with_context(|| format!("cannot write {}", path.display()))
}
