//! SH responses at run time (bundle section `sh`, DRT §5 vector responses): per lit texel the
//! order-2 SH of its incident radiance (`lightfarm_proto::sh`: world frame, y up), so a
//! normal-mapped surface can be shaded at any perturbed normal.
//!
//! [`Runtime::apply_sh`]: MRT step 1 and DRT step 2 exactly as [`Runtime::apply`] (the same
//! `b` and `c`), then for every entry `s = Z · x` (x the source's `b` or `c`, per channel) and
//! `sh[texels[i]][c][lm] += Y.row(9·i + lm) · s[c]`. No albedo: incident radiance, like a probe.
//! [`ShLight::shade`] turns it into the lightmap's quantity, outgoing radiance
//! `ρ/π · E(n')` with `E(n') = Σ Â_l L_lm Y_lm(n')` — at the geometric normal this is the scalar
//! DRT output up to SH truncation and Monte-Carlo noise (tested).
//!
//! Invariants: allocation-free per frame once `out` has the layout's size (its scratch is sized
//! on the first call); deterministic (the same direct light gives bit-identical output whatever
//! ran before); texels without rows (buried, or in a bundle without the section) stay 0.

use lightfarm_proto::sh::{irradiance_weights, sh_basis, SH_COEFFS};

use super::{dot3, set_matvec, ApplyError, Runtime};
use crate::direct::DirectLight;

/// SH incident radiance per texel: `coefficients[texel][channel][lm]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ShLight {
    pub coefficients: Vec<[[f32; SH_COEFFS]; 3]>,
    /// Per-channel `Z · x` of one entry, channel-planar (3 × the bundle's largest k).
    scratch: Vec<f32>,
}

impl ShLight {
    /// Irradiance (W/m² per channel) at texel `texel` for unit normal `n` (world frame).
    pub fn irradiance(&self, texel: usize, n: [f32; 3]) -> [f32; 3] {
        let y = sh_basis(n.map(f64::from));
        let a = irradiance_weights();
        let l = &self.coefficients[texel];
        let mut e = [0.0f32; 3];
        for (c, ec) in e.iter_mut().enumerate() {
            for lm in 0..SH_COEFFS {
                *ec += (a[lm] * y[lm]) as f32 * l[c][lm];
            }
        }
        e
    }

    /// Outgoing radiance of a Lambertian texel with perturbed unit normal `n` and `albedo`:
    /// `ρ/π · E(n)`, the quantity [`crate::IndirectLight`] holds (albedo included).
    pub fn shade(&self, texel: usize, n: [f32; 3], albedo: [f32; 3]) -> [f32; 3] {
        let e = self.irradiance(texel, n);
        let inv_pi = std::f32::consts::FRAC_1_PI;
        [0, 1, 2].map(|c| albedo[c] * inv_pi * e[c])
    }
}

impl Runtime {
    /// Whether [`Runtime::apply_sh`] is available (the bundle has an `sh` section).
    pub fn has_sh(&self) -> bool {
        self.bundle.sh.is_some()
    }

    /// Turns direct light into every texel's SH incident radiance, writing every value of `out`
    /// (resized if its texel count is wrong; otherwise no allocation after the first call).
    /// Errors: [`ApplyError::DirectLength`] (checked first), then [`ApplyError::MissingSh`].
    pub fn apply_sh(&mut self, direct: &DirectLight, out: &mut ShLight) -> Result<(), ApplyError> {
        let n = self.n_texels;
        if direct.radiance.len() != n {
            return Err(ApplyError::DirectLength {
                expected: n,
                got: direct.radiance.len(),
            });
        }
        let Some(max_rank) = self.bundle.sh.as_ref().map(|s| s.max_rank()) else {
            return Err(ApplyError::MissingSh);
        };
        if out.coefficients.len() != n {
            out.coefficients.clear();
            out.coefficients.resize(n, [[0.0; SH_COEFFS]; 3]);
        } else {
            out.coefficients.fill([[0.0; SH_COEFFS]; 3]);
        }
        if out.scratch.len() < 3 * max_rank {
            out.scratch.resize(3 * max_rank, 0.0);
        }
        self.project_blocks(&direct.radiance);
        self.project_clutter();
        let Some(sh) = &self.bundle.sh else {
            return Ok(());
        };
        let ShLight {
            coefficients,
            scratch,
        } = out;
        for e in &sh.entries {
            let k = e.z.rows as usize;
            if k == 0 {
                continue;
            }
            let x = self.source_coefficients(e.source, e.z.cols as usize);
            set_matvec(&mut scratch[..3 * k], k, &e.z, x);
            let s = [&scratch[..k], &scratch[k..2 * k], &scratch[2 * k..3 * k]];
            for (&t, rows) in e.texels.iter().zip(e.y.data.chunks_exact(SH_COEFFS * k)) {
                let o = &mut coefficients[t as usize];
                for (lm, row) in rows.chunks_exact(k).enumerate() {
                    let v = dot3(row, s);
                    o[0][lm] += v[0];
                    o[1][lm] += v[1];
                    o[2][lm] += v[2];
                }
            }
        }
        Ok(())
    }
}
