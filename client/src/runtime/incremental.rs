//! Relighting that follows what changed ([`Runtime::apply_delta`]): the operators are linear,
//! so when some lights move only the change of direct light `Δ = L_new − L_old` goes through
//! them, and only the parts of the level `Δ` reaches do work.
//!
//! Reach, per application of the one-bounce operator `A` (the [`Reach`] of its input):
//! - a block is reached when any of its texels has non-zero input: only reached blocks project
//!   (`b = T_d→b · x`, the others' `b` is 0 without a product), add `U_b b`, and feed transport
//!   entries (an entry whose sources are all unreached adds nothing and is skipped);
//! - a clutter object is reached when any of its texels has non-zero input: only reached
//!   objects project (`c = t_dc · x`) and feed delta entries; a delta entry reading direct light
//!   (`DeltaSource::Direct`) runs only when its texel range holds a non-zero value;
//! - every bounce after the first starts from the previous bounce's output, so the reach grows
//!   by one transport hop a bounce, as the light does.
//!
//! Skipped work would have multiplied exact zeros, so an application under a reach equals the
//! full application bit for bit (up to the sign of zeros); `apply_delta` then adds `A(Δ)`
//! (summed over bounces) to the old indirect light, which equals applying the new direct light
//! within float rounding for `One` and `Fixed(n)`, and within the tolerance (relative to the
//! change's own indirect light) for `Converged` (and `Warm`, which here is `Converged`: the
//! change's light has no previous answer; the answer `Warm` starts from moves by the change).
//!
//! - the exact gather runs only the rows that read a reached block's or clutter object's
//!   texels, over a four-lane copy of those texels alone (`drt::GatherByChange`, indexed on the
//!   first call): every other row would sum zeros.
//!
//! What stays proportional to the level: finding the reach (one pass over the input), the
//! planar copy of the input, the output's fill and albedo, and the sum into `out` (one pass
//! each). Those are memory passes of a few bytes a texel (about 3.5 ms a frame at 269,440
//! texels); the operator products and the gather follow the change.
//!
//! Invariant: outside [`Runtime::apply_delta`] no reach is set, so `apply` and the probes always
//! do the full work.

use super::{Applied, ApplyError, Bounces, DirectLight, IndirectLight, Method, Runtime};

/// Which blocks and clutter objects an application's input reaches (see the module doc).
#[derive(Clone, Debug, Default)]
pub(super) struct Reach {
    /// Per block: any of its texels has non-zero input.
    pub(super) blocks: Vec<bool>,
    /// Per clutter object of the DRT section: any of its texels has non-zero input.
    pub(super) clutter: Vec<bool>,
}

impl Reach {
    /// Whether the texels `range` of `light` hold any non-zero value (NaN counts as non-zero,
    /// so it propagates as in the full application).
    pub(super) fn any_light(light: &[[f32; 3]], range: std::ops::Range<usize>) -> bool {
        // `!(x == 0)` is true for NaN too.
        light[range]
            .iter()
            .any(|v| !(v[0] == 0.0 && v[1] == 0.0 && v[2] == 0.0))
    }
}

/// What one [`Runtime::apply_delta`] did, beyond [`Applied`]: how far the change reached.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DeltaApplied {
    pub applied: Applied,
    /// Block projections made, summed over the applications (a full application makes one
    /// per block).
    pub blocks_projected: usize,
    /// Blocks in the level, times the applications: what full applications would have made.
    pub blocks_total: usize,
}

impl Runtime {
    /// Fills `self.reach` from `light` (the input of one application).
    pub(super) fn find_reach(&mut self, light: &[[f32; 3]]) {
        let Some(reach) = self.reach.as_mut() else {
            return;
        };
        for (r, s) in reach.blocks.iter_mut().zip(&self.blocks) {
            *r = Reach::any_light(light, s.texel_start..s.texel_end);
        }
        if let Some(drt) = &self.bundle.drt {
            for (r, c) in reach.clutter.iter_mut().zip(&drt.clutter) {
                let start = c.texel_offset as usize;
                *r = Reach::any_light(light, start..start + c.t_dc.cols as usize);
            }
        }
        self.blocks_projected += reach.blocks.iter().filter(|r| **r).count();
    }

    /// Whether block `k` is reached (always, outside [`Runtime::apply_delta`]).
    #[inline]
    pub(super) fn block_reached(reach: Option<&Reach>, k: usize) -> bool {
        reach.is_none_or(|r| r.blocks[k])
    }

    /// Relights after a change of direct light: `out` holds the indirect light `apply(method,
    /// bounces, L)` gave for some direct light L, `delta` is the change `L_new − L` (zero
    /// wherever the change does not reach); `out` becomes the indirect light of `L_new`,
    /// computing only what `delta` reaches (module doc). `Feedback` is refused (its state is
    /// the previous frame's output, not a function of the direct light); `Warm` solves the
    /// change like `Converged`; `Full` does the full work on `delta`.
    ///
    /// On an error `out` is unchanged.
    pub fn apply_delta(
        &mut self,
        method: Method,
        bounces: Bounces,
        delta: &DirectLight,
        out: &mut IndirectLight,
    ) -> Result<DeltaApplied, ApplyError> {
        let bounces = match bounces {
            Bounces::Feedback => return Err(ApplyError::DeltaFeedback),
            // The change's own light has no previous answer to start from.
            Bounces::Warm { tolerance } => Bounces::Converged { tolerance },
            b => b,
        };
        if out.radiance.len() != self.n_texels {
            return Err(ApplyError::DirectLength {
                expected: self.n_texels,
                got: out.radiance.len(),
            });
        }
        let mut change = std::mem::take(&mut self.delta_out);
        if method != Method::Full {
            let n_clutter = self.bundle.drt.as_ref().map_or(0, |d| d.clutter.len());
            let mut reach = self.spare_reach.take().unwrap_or_default();
            reach.blocks.resize(self.blocks.len(), false);
            reach.clutter.resize(n_clutter, false);
            self.reach = Some(reach);
        }
        self.blocks_projected = 0;
        self.by_change = true;
        let result = self.apply(method, bounces, delta, &mut change);
        self.by_change = false;
        self.spare_reach = self.reach.take();
        if matches!(bounces, Bounces::Converged { .. }) && result.is_ok() {
            // The answer `Warm` starts from moves with the light.
            self.warm.add_change(method, &change.radiance);
        }
        let result = result.map(|applied| {
            for (o, d) in out.radiance.iter_mut().zip(&change.radiance) {
                o[0] += d[0];
                o[1] += d[1];
                o[2] += d[2];
            }
            let total = self.blocks.len() * applied.bounces as usize;
            DeltaApplied {
                applied,
                blocks_projected: if method == Method::Full {
                    total
                } else {
                    self.blocks_projected
                },
                blocks_total: total,
            }
        });
        self.delta_out = change;
        result
    }
}
