//! SH responses at run time (bundle section `sh`, DRT §5 vector responses): per lit texel the
//! order-2 SH of its incident radiance (`lightfarm_proto::sh`: world frame, y up), so a
//! normal-mapped surface can be shaded at any perturbed normal.
//!
//! [`Runtime::apply_sh`]: MRT step 1 and DRT step 2 exactly as [`Runtime::apply`] (the same
//! `b` and `c`), then for every entry `s = Z · x` (x the source's `b` or `c`, per channel) and
//! `sh[texels[i]][c][lm] += Y.row(9·i + lm) · s[c]`, with `Y` and `Z` packed like every other
//! operator (`crate::packed`). No albedo: incident radiance, like a probe.
//! [`ShLight::shade`] turns it into the lightmap's quantity, outgoing radiance
//! `ρ/π · E(n')` with `E(n') = Σ Â_l L_lm Y_lm(n')` — at the geometric normal this is the scalar
//! DRT output up to SH truncation and Monte-Carlo noise (tested).
//!
//! Invariants: allocation-free per frame once `out` has the layout's size (its scratch is sized
//! on the first call); deterministic (the same direct light gives bit-identical output whatever
//! ran before); texels without rows (buried, or in a bundle without the section) stay 0.

use lightfarm_proto::sh::{irradiance_weights, sh_basis, SH_COEFFS};

use super::kernels::set_matvec;
use super::{ApplyError, Runtime};
use crate::direct::DirectLight;

/// SH incident radiance per texel: `coefficients[texel][channel][lm]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ShLight {
    pub coefficients: Vec<[[f32; SH_COEFFS]; 3]>,
    /// Per-channel `Z · x` of one entry, channel-planar (3 × the bundle's largest k), then the
    /// packed products' scratch.
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
        let scratch_len = 3 * max_rank + self.ops.sh_scratch;
        if out.scratch.len() < scratch_len {
            out.scratch.resize(scratch_len, 0.0);
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
        for ((e, z), y) in sh.entries.iter().zip(&self.ops.sh_z).zip(&self.ops.sh_y) {
            let k = z.rows();
            if k == 0 {
                continue;
            }
            let x = self.source_coefficients(e.source, z.cols());
            let (s, rest) = scratch.split_at_mut(3 * k);
            set_matvec(s, k, z, x, rest);
            let s = [&s[..k], &s[k..2 * k], &s[2 * k..3 * k]];
            // Row 9·i + lm of Y is coefficient lm of texel texels[i].
            y.matvec(s, rest, |row, v| {
                let o = &mut coefficients[e.texels[row / SH_COEFFS] as usize];
                let lm = row % SH_COEFFS;
                o[0][lm] += v[0];
                o[1][lm] += v[1];
                o[2][lm] += v[2];
            });
        }
        Ok(())
    }
}
