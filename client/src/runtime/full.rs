//! [`Method::Full`](super::Method::Full): `l_ind = ρ ⊙ (F · l_d)` with the bundle's sparse
//! dense-bounce operator `F` (CSR rows over all texels, baked with `--full`), the reference the
//! reduced methods are measured against.
//!
//! Units: direct outgoing radiance in, indirect outgoing radiance out (albedo included).
//! Invariants: a no-op without the operator (`apply` refuses `Full` first); every texel of
//! `out` is written; rows are summed in column order, so results are deterministic.

use super::Runtime;

impl Runtime {
    pub(super) fn apply_full(&self, direct: &[[f32; 3]], out: &mut [[f32; 3]]) {
        let Some(f) = &self.bundle.full else { return };
        let albedo = &self.bundle.layout.albedo;
        for ((o, rho), w) in out.iter_mut().zip(albedo).zip(f.row_start.windows(2)) {
            let (start, end) = (w[0] as usize, w[1] as usize);
            let mut s = [0.0f32; 3];
            for (&c, &v) in f.cols[start..end].iter().zip(&f.values[start..end]) {
                let l = direct[c as usize];
                s[0] += v * l[0];
                s[1] += v * l[1];
                s[2] += v * l[2];
            }
            *o = [rho[0] * s[0], rho[1] * s[1], rho[2] * s[2]];
        }
    }
}
