//! `eval --sh-out FILE`: every texel's SH incident radiance (bundle section `sh`) for the light
//! set, through the client exactly as a game would (`Runtime::apply_sh`, direct light averaged
//! over each texel as for `Runtime::apply`).
//!
//! File: raw little-endian f32, layout texel order, 27 values per texel: channel-major R, G, B,
//! each the 9 coefficients of `lightfarm_proto::sh` (world frame, y up; incident radiance, no
//! albedo). Texels the bake left without rows (buried) are 0.

use std::path::Path;

use anyhow::Context;
use lightfarm_client::{Occluders, Runtime, ShLight};
use lightfarm_proto::bundle::Bundle;
use lightfarm_proto::lights::LightSet;

use super::eval::operator_direct;

/// The SH incident radiance of every texel for `lights`.
pub fn sh_incident(bundle: Bundle, lights: &LightSet) -> anyhow::Result<ShLight> {
    let occluders = Occluders::from_layout(&bundle.layout);
    let direct = operator_direct(&bundle.layout, &occluders, &lights);
    let mut runtime = Runtime::try_new(bundle)?;
    let mut out = ShLight::default();
    runtime.apply_sh(&direct, &mut out)?;
    Ok(out)
}

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
