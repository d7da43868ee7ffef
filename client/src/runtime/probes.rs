//! [`Runtime::apply_probes`](super::Runtime::apply_probes): the SH radiance of every probe of
//! the bundle's probe volume, from the same `b` and `c` as `apply` (MRT step 1, DRT step 2),
//! then every probe entry `field[rows[i]] += matrix.row(i) · x` with `rows[i] = probe · 9 +
//! coefficient` (for a low-rank entry, format 2.3: `matrix.row(i) · y` with `y = mix · x`
//! made first, as DRT's low-rank deltas are); and
//! [`Runtime::apply_probes_delta`](super::Runtime::apply_probes_delta), which adds the field of
//! a change of light to a field made before.
//!
//! Work follows what the probes read, not the level: the entries' sources ([`ProbeSources`],
//! found with the runtime) are the only blocks and clutter objects projected, and only on
//! their texels is the input copied, with the machinery of relighting by the change (module
//! `incremental`: the reach of the input, `ld` filled on the reached units alone, a block's
//! projection reading its columns of non-zero input). A probe volume follows the dynamic
//! objects' regions, so its entries read a neighbourhood: on a generated 320-block level with
//! one ball, 40 blocks and 2 clutter objects. Where the sources hold half the level's texels
//! or more, `apply_probes` copies the whole light instead (cheaper than finding where it lies
//! there) and still projects the sources alone. By the change, only the sources the change
//! reaches are projected and only their entries run.
//!
//! Units: incident radiance at a point (order-2 SH per channel), no albedo; the field is read
//! by [`crate::probes::irradiance_at`].
//!
//! Invariants: errors are only [`ApplyError::DirectLength`], [`ApplyError::MissingProbes`] and
//! (by the change) [`ApplyError::ProbeFieldSize`]; probes no entry feeds stay 0; every value
//! equals the whole projection's (up to the sign of zeros: what is skipped multiplies zeros),
//! and by the change the sum of the two fields' within float rounding; no allocation once
//! `out` has the volume's size.

use std::ops::Range;

use lightfarm_proto::bundle::DeltaSource;

use super::incremental::{merge_spans, Sparse};
use super::kernels::{planar, set_matvec};
use super::{ApplyError, Runtime};
use crate::direct::DirectLight;
use crate::probes::ProbeField;

/// What the probe entries read: per block and per clutter object whether an entry's source
/// is its coefficients, and the texel ranges of those sources (ascending, disjoint) with
/// their texel count.
#[derive(Clone, Debug)]
pub(super) struct ProbeSources {
    blocks: Vec<bool>,
    clutter: Vec<bool>,
    spans: Vec<Range<usize>>,
    texels: usize,
}

impl ProbeSources {
    pub(super) fn new(rt: &Runtime) -> ProbeSources {
        let n_clutter = rt.bundle.drt.as_ref().map_or(0, |d| d.clutter.len());
        let mut sources = ProbeSources {
            blocks: vec![false; rt.blocks.len()],
            clutter: vec![false; n_clutter],
            spans: Vec::new(),
            texels: 0,
        };
        let Some(probes) = &rt.bundle.probes else {
            return sources;
        };
        let mut spans = Vec::new();
        for e in &probes.entries {
            match e.source {
                DeltaSource::Block(k) => {
                    let s = &rt.blocks[k as usize];
                    sources.blocks[k as usize] = true;
                    spans.push(s.texel_start..s.texel_end);
                }
                DeltaSource::Clutter(j) => {
                    let c = &rt.bundle.drt.as_ref().expect("checked at load").clutter[j as usize];
                    let start = c.texel_offset as usize;
                    sources.clutter[j as usize] = true;
                    spans.push(start..start + c.t_dc.cols as usize);
                }
                DeltaSource::Direct { first, count } => {
                    spans.push(first as usize..first as usize + count as usize);
                }
            }
        }
        merge_spans(&mut spans);
        sources.spans = spans;
        sources.texels = sources.spans.iter().map(Range::len).sum();
        sources
    }
}

impl Runtime {
    /// Turns direct light into the SH radiance of every probe of the bundle's probe volume,
    /// writing every value of `out` (resized if its probe count is wrong; otherwise no
    /// allocation). Only the blocks and clutter objects the probe entries read are projected
    /// (module doc). Errors: [`ApplyError::DirectLength`] (checked first), then
    /// [`ApplyError::MissingProbes`].
    pub fn apply_probes(
        &mut self,
        direct: &DirectLight,
        out: &mut ProbeField,
    ) -> Result<(), ApplyError> {
        let n_probes = self.check_probe_input(direct)?;
        out.reset(n_probes);
        self.add_probes_of(&direct.radiance, None, out);
        Ok(())
    }

    /// Adds the probe field of a change of light to `field`: `field` holds what
    /// [`Runtime::apply_probes`] gave for some light L, `change` is `L_new − L`, zero outside
    /// the texel ranges `spans`; `field` becomes the field of `L_new` within float rounding,
    /// and only the probe entries whose sources the change reaches run (module doc). What the
    /// probes read is the light leaving the surfaces: at one bounce the direct light, with
    /// bounces direct plus indirect, so the change is the change of direct light plus the
    /// change of indirect light that [`Runtime::apply_delta_in`] made (on
    /// [`Runtime::delta_written`]'s ranges, which then belong in `spans`). A non-zero value
    /// outside `spans` is not seen. On an error `field` is unchanged.
    ///
    /// Errors: [`ApplyError::DirectLength`], [`ApplyError::MissingProbes`], and
    /// [`ApplyError::ProbeFieldSize`] when `field` does not hold the volume's probes.
    pub fn apply_probes_delta(
        &mut self,
        change: &DirectLight,
        spans: &[Range<usize>],
        field: &mut ProbeField,
    ) -> Result<(), ApplyError> {
        let n_probes = self.check_probe_input(change)?;
        if field.n_probes() != n_probes {
            return Err(ApplyError::ProbeFieldSize {
                expected: n_probes,
                got: field.n_probes(),
            });
        }
        self.add_probes_of(&change.radiance, Some(spans), field);
        Ok(())
    }

    /// The texel ranges the probe entries read (ascending, disjoint; empty without a probe
    /// volume): a change of light elsewhere moves no probe, so only its part on these ranges
    /// needs to reach [`Runtime::apply_probes_delta`].
    pub fn probe_source_spans(&self) -> &[Range<usize>] {
        self.probe_sources.as_ref().map_or(&[], |s| &s.spans)
    }

    /// The volume's probe count, after checking `light`'s length and that there is a volume.
    fn check_probe_input(&self, light: &DirectLight) -> Result<usize, ApplyError> {
        if light.radiance.len() != self.n_texels {
            return Err(ApplyError::DirectLength {
                expected: self.n_texels,
                got: light.radiance.len(),
            });
        }
        self.bundle
            .probes
            .as_ref()
            .map(|p| p.n_probes as usize)
            .ok_or(ApplyError::MissingProbes)
    }

    /// Adds the probe entries of `light` (read on the sources' texels within `spans`, or on
    /// all of them) to `out`: the reach of the input on those texels, restricted to the
    /// entries' sources, then the sources' projections and their entries.
    fn add_probes_of(
        &mut self,
        light: &[[f32; 3]],
        spans: Option<&[Range<usize>]>,
        out: &mut ProbeField,
    ) {
        let sources = self
            .probe_sources
            .take()
            .unwrap_or_else(|| ProbeSources::new(self));
        let n_clutter = sources.clutter.len();
        let mut reach = self.spare_reach.take().unwrap_or_default();
        reach.blocks.resize(self.blocks.len(), false);
        reach.clutter.resize(n_clutter, false);
        if spans.is_none() && 2 * sources.texels >= self.n_texels {
            // The sources hold most of the level: one copy of the whole light and the sources'
            // projections cost less than finding where it lies (the same values).
            reach.blocks.copy_from_slice(&sources.blocks);
            reach.clutter.copy_from_slice(&sources.clutter);
            self.reach = Some(reach);
            self.project_blocks(light);
            self.project_clutter();
            self.add_probe_entries(out);
            self.spare_reach = self.reach.take();
            self.probe_sources = Some(sources);
            return;
        }
        self.reach = Some(reach);
        let mut sparse = self.sparse.take().unwrap_or_else(|| Sparse::new(self));
        self.load_sparse_input(&mut sparse, light, Some(spans.unwrap_or(&sources.spans)));
        let reach = self.reach.as_mut().expect("set above");
        for (r, &s) in reach.blocks.iter_mut().zip(&sources.blocks) {
            *r &= s;
        }
        for (r, &s) in reach.clutter.iter_mut().zip(&sources.clutter) {
            *r &= s;
        }
        sparse.active = true;
        self.sparse = Some(sparse);
        self.project_blocks(light);
        self.project_clutter();
        self.sparse.as_mut().expect("set above").active = false;
        self.add_probe_entries(out);
        self.spare_reach = self.reach.take();
        self.probe_sources = Some(sources);
    }

    /// Probe step, after [`Runtime::project_blocks`] and [`Runtime::project_clutter`]: adds
    /// every probe entry whose source the reach holds (every entry without a reach) to a field
    /// of the volume's size. Does nothing without a probe volume.
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
            if !self.source_reached(e.source) {
                // Its coefficients are exact zeros: the entry would add zeros.
                continue;
            }
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
