//! [`Runtime::apply_probes`](super::Runtime::apply_probes): the SH radiance of every probe of
//! the bundle's probe volume, from the same `b` and `c` as `apply` (MRT step 1, DRT step 2),
//! then every probe entry `field[rows[i]] += matrix.row(i) · x` with `rows[i] = probe · 9 +
//! coefficient` (for a low-rank entry, format 2.3: `matrix.row(i) · y` with `y = mix · x`
//! made first, as DRT's low-rank deltas are).
//!
//! Units: incident radiance at a point (order-2 SH per channel), no albedo; the field is read
//! by [`crate::probes::irradiance_at`].
//!
//! Invariants: errors are only [`ApplyError::DirectLength`] and
//! [`ApplyError::MissingProbes`]; probes no entry feeds stay 0; no allocation once `out` has the
//! volume's size.

use super::kernels::{planar, set_matvec};
use super::{ApplyError, Runtime};
use crate::direct::DirectLight;
use crate::probes::ProbeField;

impl Runtime {
    /// Turns direct light into the SH radiance of every probe of the bundle's probe volume,
    /// writing every value of `out` (resized if its probe count is wrong; otherwise no
    /// allocation). Errors: [`ApplyError::DirectLength`] (checked first), then
    /// [`ApplyError::MissingProbes`].
    pub fn apply_probes(
        &mut self,
        direct: &DirectLight,
        out: &mut ProbeField,
    ) -> Result<(), ApplyError> {
        let n = self.n_texels;
        if direct.radiance.len() != n {
            return Err(ApplyError::DirectLength {
                expected: n,
                got: direct.radiance.len(),
            });
        }
        let Some(n_probes) = self.bundle.probes.as_ref().map(|p| p.n_probes as usize) else {
            return Err(ApplyError::MissingProbes);
        };
        out.reset(n_probes);
        self.project_blocks(&direct.radiance);
        self.project_clutter();
        self.add_probe_entries(out);
        Ok(())
    }

    /// Probe step, after [`Runtime::project_blocks`] and [`Runtime::project_clutter`], into a
    /// zeroed field of the volume's size: adds every probe entry. Does nothing without a probe
    /// volume.
    fn add_probe_entries(&mut self, out: &mut ProbeField) {
        let Some(probes) = &self.bundle.probes else {
            return;
        };
        let mut scratch = std::mem::take(&mut self.scratch);
        for ((e, m), mix) in probes
            .entries
            .iter()
            .zip(&self.ops.probes)
            .zip(&self.ops.probe_mix)
        {
            match mix {
                None => {
                    let x = self.source_coefficients(e.source, m.cols());
                    m.matvec(x, &mut scratch, |i, v| out.add_row(e.rows[i], v));
                }
                Some(mix) => {
                    // Low rank: y = mix · x (k values per channel), then rows += matrix · y.
                    let k = mix.rows();
                    let (y, rest) = scratch.split_at_mut(3 * k);
                    let x = self.source_coefficients(e.source, mix.cols());
                    set_matvec(y, k, mix, x, rest);
                    m.matvec(planar(y, k, 0, k), rest, |i, v| out.add_row(e.rows[i], v));
                }
            }
        }
        self.scratch = scratch;
    }
}
