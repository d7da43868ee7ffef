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
//!   by one transport hop a bounce, as the light does (`Converged` with MRT, and with DRT where
//!   its coefficient space is kept, instead projects the reached blocks and clutter once and
//!   runs the bounces in coefficient space, modules `reduced` and `reduced_drt`);
//! - the exact gather runs by column (`drt::GatherByChange`, made on the first call): only the
//!   entries reading a texel of a reached block or clutter object whose input is not zero,
//!   each row's terms summed in that order (the whole gather sums them row by row).
//!
//! Skipped work would have multiplied exact zeros, so an application under a reach equals the
//! full application bit for bit (up to the sign of zeros), but for the exact gather's rows,
//! which agree to float rounding (their terms in another order); `apply_delta` then adds `A(Δ)`
//! (summed over bounces) to the old indirect light, which equals applying the new direct light
//! within float rounding for `One` and `Fixed(n)`, and within the tolerance (relative to the
//! change's own indirect light) for `Converged` (and `Warm`, which here is `Converged`: the
//! change's light has no previous answer; the answer `Warm` starts from moves by the change).
//!
//! At one bounce (`One`, `Fixed(1)`) nothing else passes over the level either ([`Sparse`]):
//! the planar copy of the input covers the reached blocks and clutter objects only (the last
//! call's copy is cleared where it was), the change's light is cleared, scaled by the albedo
//! and added to `out` only on the blocks and clutter objects written (MRT's blocks, the delta
//! entries' rows, the gather's rows), and unreached blocks' coefficients are never written nor
//! read. What stays proportional to the level there is finding the reach (one read of the
//! input, per unit until its first non-zero value; none when the caller names the spans the
//! change lies in, [`Runtime::apply_delta_in`]) and loops over blocks and entries without
//! products. More bounces (`Fixed(n ≥ 2)`, `Converged`, `Warm`) chain those one-bounce
//! applications, each on the light of the bounce before, where the change's light goes and,
//! for `Converged`, while it matters (module `delta_bounces`); a change whose light fills the
//! level takes whole-level applications under a reach (GMRES, or the coefficient-space
//! solves).
//!
//! grid1000, one light moving, all bounces (`Converged`, 1e-3), one thread: the operators'
//! part of a frame went from 40–42 ms (GMRES over whole vectors) to 4.5–5.9 ms (16 bounces over
//! about 4,000 texels each); the maze's change fills most of it and keeps the
//! coefficient-space solve (5.2–5.8 ms).
//!
//! grid1000 (269,440 texels, 1,000 blocks), one light moving, one bounce, one thread: the
//! operators' part of a frame went from 10.9 ms (whole-level passes and the whole gather) to
//! 2.0 ms.
//!
//! The maze (T=16), one light moving, one bounce: a frame's products read 1.94 M packed
//! entries, all 8-bit (2.1 MB; DRT's delta entries, on floored 8-bit grids, were read as f32
//! before `packed` recognised those grids: 3.5 MB), and perf puts about half of the
//! operators' time in those products. The bytes are not the bound: a quarter of them for the
//! deltas made the operators' part 0.77–0.83 → 0.72–0.75 ms (with 16-row panels; three
//! interleaved runs each), and without the full way's passes between frames (caches warm; a
//! temporary switch) it was 0.51–0.54 ms either way.
//!
//! Invariant: outside [`Runtime::apply_delta`] no reach is set, so `apply` and the probes always
//! do the full work.

use std::ops::Range;

use super::{Applied, ApplyError, Bounces, DirectLight, IndirectLight, Method, Runtime};
use crate::packed_gather::texel_units;
use lightfarm_proto::bundle::{DeltaSource, TransportOps};

/// Texels apart that [`nonzero_runs`] still joins into one run (reading a few zero columns
/// costs less than starting another run).
const RUN_GAP: usize = 8;

/// The runs of `light` (indices from its start) holding a value that is not zero in some
/// channel (NaN is not zero), joined across gaps of fewer than [`RUN_GAP`] zeros, into `runs`.
fn nonzero_runs(light: &[[f32; 3]], runs: &mut Vec<Range<usize>>) {
    runs.clear();
    for (t, v) in light.iter().enumerate() {
        if v[0] == 0.0 && v[1] == 0.0 && v[2] == 0.0 {
            continue;
        }
        match runs.last_mut() {
            Some(last) if t - last.end < RUN_GAP => last.end = t + 1,
            _ => runs.push(t..t + 1),
        }
    }
}

/// Sorts texel ranges and joins those that overlap or touch, in place: ascending, disjoint
/// (what [`Runtime::apply_delta_in`] and [`Runtime::apply_probes_delta`] take), holding the
/// same texels. Allocates nothing.
pub fn merge_spans(spans: &mut Vec<Range<usize>>) {
    spans.sort_unstable_by_key(|r| r.start);
    let mut kept = 0usize;
    for i in 0..spans.len() {
        let r = spans[i].clone();
        match kept.checked_sub(1).map(|k| &mut spans[k]) {
            Some(last) if r.start <= last.end => last.end = last.end.max(r.end),
            _ => {
                spans[kept] = r;
                kept += 1;
            }
        }
    }
    spans.truncate(kept);
}

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

/// Relighting by the change at one bounce in work that follows the change only (see
/// [`Runtime::apply_delta`]): the level's texels as units (blocks, clutter objects, then the
/// texels in neither), and which units of the planar direct light `ld` and of the change's
/// indirect light may be non-zero, so nothing passes over the whole level.
#[derive(Clone, Debug)]
pub(super) struct Sparse {
    ranges: Vec<Range<usize>>,
    n_blocks: usize,
    n_clutter: usize,
    /// Per texel: its unit.
    unit_of: Vec<u32>,
    /// Units whose `ld` values may be non-zero (every other value of `ld` is 0).
    in_ld: Vec<usize>,
    /// Units of the change's indirect light (`delta_out`) that may be non-zero, each once
    /// (`marked` while listed); `change_everywhere`: a call that was not sparse wrote it all.
    written: Vec<usize>,
    marked: Vec<bool>,
    change_everywhere: bool,
    /// Units this call's input reaches, and a flag per unit while they are listed.
    reached: Vec<usize>,
    listed: Vec<bool>,
    /// While the stages run for a sparse call (`project_blocks` and `mrt_albedo_free` then
    /// skip their passes over the level).
    pub(super) active: bool,
    /// Per source block `s`: the blocks that transport entries carry its light into,
    /// `targets[target_start[s] .. target_start[s + 1]]` (ascending, each once).
    targets: Vec<u32>,
    target_start: Vec<u32>,
    /// Scratch: the blocks this call writes (the reached ones and their targets).
    blocks_written: Vec<u32>,
    /// Per unit: the DRT delta entries whose source reads it (a block's or clutter object's
    /// coefficients, or a `Direct` source's texels overlapping it),
    /// `unit_entries[unit_entry_start[u] .. unit_entry_start[u + 1]]` ascending.
    unit_entries: Vec<u32>,
    unit_entry_start: Vec<u32>,
    /// Scratch: the entries this call's reached units may move.
    entries: Vec<u32>,
    /// Per DRT delta entry: the units of its rows, each once in the order the rows first
    /// reach them, `entry_units[entry_unit_start[i] .. entry_unit_start[i + 1]]`.
    entry_units: Vec<u32>,
    entry_unit_start: Vec<u32>,
    /// Per block, while it is reached: the runs of its texels (from the block's first) whose
    /// input is not zero in every channel, so its projection reads those columns alone.
    nonzero: Vec<Vec<Range<usize>>>,
}

impl Sparse {
    /// Block `k`'s runs of non-zero input while the stages of a sparse call run (`None`
    /// otherwise: read every column).
    pub(super) fn nonzero_columns(&self, k: usize) -> Option<&[Range<usize>]> {
        self.active.then(|| self.nonzero[k].as_slice())
    }

    pub(super) fn new(rt: &Runtime) -> Sparse {
        let units = rt.texel_units();
        let n_blocks = rt.blocks.len();
        let n_clutter = units.len() - n_blocks;
        let (ranges, unit_of) = texel_units(&units, rt.n_texels);
        let (targets, target_start) = transport_targets(rt);
        let (unit_entries, unit_entry_start) = delta_entries_by_unit(rt, n_blocks, &unit_of);
        let rows = rt
            .bundle
            .drt
            .iter()
            .flat_map(|d| &d.entries)
            .map(|e| &e.rows[..]);
        let (entry_units, entry_unit_start) = units_of_rows(rows, &unit_of, ranges.len());
        Sparse {
            unit_entries,
            unit_entry_start,
            entries: Vec::new(),
            entry_units,
            entry_unit_start,
            targets,
            target_start,
            blocks_written: Vec::new(),
            marked: vec![false; ranges.len()],
            listed: vec![false; ranges.len()],
            ranges,
            n_blocks,
            n_clutter,
            unit_of,
            in_ld: Vec::new(),
            written: Vec::new(),
            change_everywhere: true,
            reached: Vec::new(),
            active: false,
            nonzero: vec![Vec::new(); n_blocks],
        }
    }

    /// The DRT delta entries a source reached by this call may move, ascending, each once: a
    /// superset of those whose source is reached (`Runtime::source_reached`), since every such
    /// source reads a reached unit. Taken out of the sparse state; hand it back with
    /// [`Sparse::give_back_entries`].
    pub(super) fn reached_entries(&mut self) -> Vec<u32> {
        let mut entries = std::mem::take(&mut self.entries);
        entries.clear();
        for &u in &self.reached {
            let r = self.unit_entry_start[u] as usize..self.unit_entry_start[u + 1] as usize;
            entries.extend_from_slice(&self.unit_entries[r]);
        }
        entries.sort_unstable();
        entries.dedup();
        entries
    }

    pub(super) fn give_back_entries(&mut self, entries: Vec<u32>) {
        self.entries = entries;
    }

    /// The blocks transport carries block `s`'s light into.
    fn targets_of(&self, s: usize) -> &[u32] {
        &self.targets[self.target_start[s] as usize..self.target_start[s + 1] as usize]
    }

    fn mark(&mut self, u: usize) {
        if !self.marked[u] {
            self.marked[u] = true;
            self.written.push(u);
        }
    }

    /// Marks the units of DRT delta entry `i`'s rows as written (it scatters into them), in
    /// the order its rows first reach them, from a list made once.
    pub(super) fn mark_entry_rows(&mut self, i: usize) {
        let r = self.entry_unit_start[i] as usize..self.entry_unit_start[i + 1] as usize;
        for k in r {
            self.mark(self.entry_units[k] as usize);
        }
    }

    /// Marks `units` as written, in order (the stages that scatter into rows call this, or
    /// [`Sparse::mark_entry_rows`], while the call is active).
    pub(super) fn mark_units(&mut self, units: &[u32]) {
        for &u in units {
            self.mark(u as usize);
        }
    }

    /// Whether block `k`'s texels are written this call (marked before MRT runs).
    pub(super) fn writes_block(&self, k: usize) -> bool {
        self.marked[k]
    }

    /// The units' texel ranges: the blocks, the clutter objects, then the runs of texels in
    /// neither.
    pub(super) fn ranges(&self) -> &[Range<usize>] {
        &self.ranges
    }

    /// The units the last call wrote (its output may be non-zero there only), each once.
    pub(super) fn written(&self) -> &[usize] {
        &self.written
    }

    /// Calls `f(unit)` for each unit `spans` touch, in span order (a unit may come more
    /// than once).
    pub(super) fn units_in(&self, spans: &[Range<usize>], mut f: impl FnMut(usize)) {
        let n = self.unit_of.len();
        for_each_unit_in(&self.unit_of, &self.ranges, spans, n, |u, _| f(u));
    }

    /// The texels of the blocks a one-bounce call with input on `spans` writes at the least
    /// (the blocks the spans touch and the blocks transport carries their light into), without
    /// reading the input.
    pub(super) fn spread_texels(&mut self, spans: &[Range<usize>]) -> usize {
        let mut listed = std::mem::take(&mut self.blocks_written);
        listed.clear();
        let n = self.unit_of.len();
        for_each_unit_in(&self.unit_of, &self.ranges, spans, n, |u, _| {
            if u < self.n_blocks {
                listed.push(u as u32);
                listed.extend_from_slice(self.targets_of(u));
            }
        });
        listed.sort_unstable();
        listed.dedup();
        let texels = listed.iter().map(|&k| self.ranges[k as usize].len()).sum();
        self.blocks_written = listed;
        texels
    }
}

/// What one [`Runtime::apply_delta`] did, beyond [`Applied`]: how far the change reached.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DeltaApplied {
    pub applied: Applied,
    /// Block projections made, summed over the applications (a full application makes one
    /// per block), by the path that answered (not counting a bounce-by-bounce start that
    /// gave up).
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

    /// The texel ranges of the blocks, then of the clutter objects: the units relighting by
    /// the change works in.
    pub(super) fn texel_units(&self) -> Vec<Range<usize>> {
        let blocks = self.blocks.iter().map(|s| s.texel_start..s.texel_end);
        let clutter = self.bundle.drt.iter().flat_map(|d| {
            d.clutter.iter().map(|c| {
                let start = c.texel_offset as usize;
                start..start + c.t_dc.cols as usize
            })
        });
        blocks.chain(clutter).collect()
    }

    /// The texel ranges in which the last successful [`Runtime::apply_delta`] (or
    /// [`Runtime::apply_delta_in`]) may have changed its `out`: `Some` after a call that
    /// worked by the change (the blocks, clutter objects and other texel runs it wrote, each
    /// once: at one bounce, or bounce by bounce), `None` when it may have changed every texel
    /// (whole-level applications, [`Method::Full`], or no such call yet). A caller keeping its
    /// own copy of the indirect light can pass zeros as `out` and add them to its copy on these
    /// ranges alone.
    pub fn delta_written(&self) -> Option<impl Iterator<Item = Range<usize>> + '_> {
        let s = self.sparse.as_ref()?;
        let units = match self.chain.as_ref().filter(|c| c.answered) {
            Some(chain) => chain.sum_units(),
            None if !s.change_everywhere => &s.written,
            None => return None,
        };
        Some(units.iter().map(|&u| s.ranges[u].clone()))
    }

    /// The sparse state's unit ranges (made by [`Runtime::prepare_delta`]).
    pub(super) fn sparse_ranges(&self) -> &[Range<usize>] {
        self.sparse
            .as_ref()
            .expect("prepare_delta made it")
            .ranges()
    }

    /// Whether block `k` is reached (always, outside [`Runtime::apply_delta`]).
    #[inline]
    pub(super) fn block_reached(reach: Option<&Reach>, k: usize) -> bool {
        reach.is_none_or(|r| r.blocks[k])
    }

    /// Makes now what relighting by the change otherwise makes on its first call (the exact
    /// gather by column, the scratch of one-bounce updates), so that the first
    /// [`Runtime::apply_delta`] costs what the later ones do: on grid1000 the first call took
    /// 91 ms against 0.4 ms after (a game calls this at level load). Changes no result;
    /// calling it again does nothing.
    pub fn prepare_delta(&mut self) {
        self.prepare_gather_by_change();
        if self.sparse.is_none() {
            self.sparse = Some(Sparse::new(self));
        }
    }

    /// Relights after a change of direct light: `out` holds the indirect light `apply(method,
    /// bounces, L)` gave for some direct light L, `delta` is the change `L_new − L` (zero
    /// wherever the change does not reach); `out` becomes the indirect light of `L_new`,
    /// computing only what `delta` reaches (module doc). `Feedback` makes one bounce of the
    /// change and of the light earlier calls added but did not bounce yet, where that light
    /// is due (module `delta_feedback`: all bounces over frames; refused with `Full`); `Warm`
    /// solves the change like `Converged`; `Full` does the full work on `delta`. More bounces
    /// than one go bounce by bounce where the change's light goes (module `delta_bounces`),
    /// or by whole-level applications when it fills the level.
    ///
    /// On an error `out` is unchanged.
    pub fn apply_delta(
        &mut self,
        method: Method,
        bounces: Bounces,
        delta: &DirectLight,
        out: &mut IndirectLight,
    ) -> Result<DeltaApplied, ApplyError> {
        self.apply_delta_impl(method, bounces, delta, None, out)
    }

    /// [`Runtime::apply_delta`] when the caller knows the texel ranges `spans` outside which
    /// `delta` is zero (e.g. where a moved light was and is, [`crate::ReachDirect::light`]'s
    /// spans): at one bounce the reach is then found on those texels alone, so not even one
    /// read passes over the level. The same results as `apply_delta` when the promise holds
    /// (checked in debug builds); a non-zero value outside the spans is not seen.
    pub fn apply_delta_in(
        &mut self,
        method: Method,
        bounces: Bounces,
        delta: &DirectLight,
        spans: &[Range<usize>],
        out: &mut IndirectLight,
    ) -> Result<DeltaApplied, ApplyError> {
        debug_assert!(
            {
                let mut inside = vec![false; delta.radiance.len()];
                for s in spans {
                    let end = s.end.min(inside.len());
                    inside[s.start.min(end)..end].fill(true);
                }
                delta
                    .radiance
                    .iter()
                    .zip(&inside)
                    .all(|(v, &i)| i || *v == [0.0; 3])
            },
            "apply_delta_in: a non-zero change outside its spans"
        );
        self.apply_delta_impl(method, bounces, delta, Some(spans), out)
    }

    fn apply_delta_impl(
        &mut self,
        method: Method,
        bounces: Bounces,
        delta: &DirectLight,
        spans: Option<&[Range<usize>]>,
        out: &mut IndirectLight,
    ) -> Result<DeltaApplied, ApplyError> {
        let bounces = match bounces {
            Bounces::Feedback if method == Method::Full => return Err(ApplyError::DeltaFeedback),
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
        if let Some(chain) = self.chain.as_mut() {
            chain.answered = false;
        }
        let progressive = bounces == Bounces::Feedback;
        let sparse = matches!(
            bounces,
            Bounces::One | Bounces::Fixed(1) | Bounces::Feedback
        ) && method != Method::Full;
        let chained = method != Method::Full
            && matches!(bounces, Bounces::Fixed(2..) | Bounces::Converged { .. })
            && self.check_arguments(method, bounces, delta).is_ok();
        let mut by_chain = false;
        let result = if progressive {
            // One bounce of the change and of the light due (module `delta_feedback`).
            self.check_arguments(method, bounces, delta)
                .map(|()| self.shoot_unshot(method, &delta.radiance, spans, &mut change.radiance))
        } else if sparse {
            self.check_arguments(method, bounces, delta).map(|()| {
                self.apply_once_sparse(method, &delta.radiance, spans, &mut change.radiance);
                Applied {
                    bounces: 1,
                    remaining_fraction: 0.0,
                }
            })
        } else {
            let answer = if chained {
                // Bounce by bounce where the change's light goes (module `delta_bounces`).
                self.apply_chain(
                    method,
                    bounces,
                    &delta.radiance,
                    spans,
                    &mut change.radiance,
                )
            } else {
                None
            };
            match answer {
                Some(result) => {
                    by_chain = true;
                    if result.is_err() {
                        // The last bounce's light may be anywhere in `change`.
                        self.sparse
                            .as_mut()
                            .expect("made by the chain")
                            .change_everywhere = true;
                    }
                    result
                }
                None => {
                    // The chain gave up (or was not tried): whole vectors, under a reach.
                    self.blocks_projected = 0;
                    if let Some(s) = self.sparse.as_mut() {
                        s.change_everywhere = true;
                    }
                    self.by_change = true;
                    let result = self.apply(method, bounces, delta, &mut change);
                    self.by_change = false;
                    result
                }
            }
        };
        self.spare_reach = self.reach.take();
        // Channel by channel as one run of floats (the same sums, in wide registers).
        let add = |o: &mut [[f32; 3]], d: &[[f32; 3]]| {
            for (o, d) in o.as_flattened_mut().iter_mut().zip(d.as_flattened()) {
                *o += d;
            }
        };
        // The change's indirect light and the units it lies on (None: anywhere).
        let (light, units): (&[[f32; 3]], Option<&[usize]>) = match &self.chain {
            Some(chain) if by_chain => (chain.sum(), Some(chain.sum_units())),
            _ => (
                &change.radiance,
                self.sparse
                    .as_ref()
                    .filter(|_| sparse)
                    .map(|s| &s.written[..]),
            ),
        };
        let ranges = self.sparse.as_ref().map_or(&[][..], |s| &s.ranges[..]);
        if matches!(bounces, Bounces::Converged { .. }) && result.is_ok() {
            // The answer `Warm` starts from moves with the light.
            match units {
                Some(units) => {
                    let spans = units.iter().map(|&u| ranges[u].clone());
                    self.warm.add_change_in(method, light, spans);
                }
                None => self.warm.add_change(method, light),
            }
        }
        let result = result.map(|applied| {
            match units {
                Some(units) => {
                    for &u in units {
                        let r = ranges[u].clone();
                        add(&mut out.radiance[r.clone()], &light[r]);
                    }
                }
                None => add(&mut out.radiance, light),
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
        let mut result = result;
        if let (true, Ok(done)) = (progressive, result.as_mut()) {
            self.judge_unshot(&change.radiance);
            done.applied.remaining_fraction = self.feedback_lag() as f32;
        }
        self.delta_out = change;
        result
    }

    /// The first step of a sparse application (one bounce by the change, or the probes): finds
    /// the units `input` reaches (every unit with a non-zero value; with `spans`, on their
    /// texels alone) into `self.reach` and `sparse.reached`, clears `ld` where the last such
    /// call (or a full copy) filled it, copies the input into `ld` on the reached units only
    /// (`sparse.in_ld`), and finds each reached block's runs of non-zero input.
    pub(super) fn load_sparse_input(
        &mut self,
        sparse: &mut Sparse,
        delta: &[[f32; 3]],
        spans: Option<&[Range<usize>]>,
    ) {
        let n = self.n_texels;
        let reach = self.reach.as_mut().expect("apply_delta sets the reach");
        sparse.reached.clear();
        match spans {
            None => {
                for (u, r) in sparse.ranges.iter().enumerate() {
                    let hit = Reach::any_light(delta, r.clone());
                    if u < sparse.n_blocks {
                        reach.blocks[u] = hit;
                    } else if u < sparse.n_blocks + sparse.n_clutter {
                        reach.clutter[u - sparse.n_blocks] = hit;
                    }
                    if hit {
                        sparse.reached.push(u);
                    }
                }
            }
            Some(spans) => {
                // A unit no span touches holds zeros only: unreached, as the scan would find.
                reach.blocks.fill(false);
                reach.clutter.fill(false);
                let n = delta.len().min(sparse.unit_of.len());
                let (listed, reached) = (&mut sparse.listed, &mut sparse.reached);
                for_each_unit_in(&sparse.unit_of, &sparse.ranges, spans, n, |u, texels| {
                    if !listed[u] && Reach::any_light(delta, texels) {
                        listed[u] = true;
                        reached.push(u);
                    }
                });
                sparse.reached.sort_unstable();
                for &u in &sparse.reached {
                    sparse.listed[u] = false;
                    if u < sparse.n_blocks {
                        reach.blocks[u] = true;
                    } else if u < sparse.n_blocks + sparse.n_clutter {
                        reach.clutter[u - sparse.n_blocks] = true;
                    }
                }
            }
        }
        if self.ld_everywhere {
            self.ld.fill(0.0);
            self.ld_everywhere = false;
        } else {
            for &u in &sparse.in_ld {
                let r = sparse.ranges[u].clone();
                for ch in 0..3 {
                    self.ld[ch * n + r.start..ch * n + r.end].fill(0.0);
                }
            }
        }
        for &u in &sparse.reached {
            let range = sparse.ranges[u].clone();
            for t in range.clone() {
                for ch in 0..3 {
                    self.ld[ch * n + t] = delta[t][ch];
                }
            }
            if u < sparse.n_blocks {
                nonzero_runs(&delta[range.clone()], &mut sparse.nonzero[u]);
            }
        }
        sparse.in_ld.clone_from(&sparse.reached);
    }

    /// One bounce of `delta` into `change` in work that follows the change (the stages of
    /// [`Runtime::apply_once`] with [`Sparse`] active): the reach and the planar copy of the
    /// input visit each unit once, `change` is cleared only where the last call wrote it, and
    /// the albedo touches only the units written. Every value equals the full application's
    /// (up to the sign of zeros): what is skipped multiplies, copies or scales zeros.
    /// With `spans`, the input is zero outside them and only their texels are read for the
    /// reach (units listed in ascending order either way).
    pub(super) fn apply_once_sparse(
        &mut self,
        method: Method,
        delta: &[[f32; 3]],
        spans: Option<&[Range<usize>]>,
        change: &mut [[f32; 3]],
    ) {
        let mut sparse = self.sparse.take().unwrap_or_else(|| Sparse::new(self));
        // The last call's light.
        if sparse.change_everywhere {
            change.fill([0.0; 3]);
            sparse.change_everywhere = false;
        } else {
            for &u in &sparse.written {
                change[sparse.ranges[u].clone()]
                    .as_flattened_mut()
                    .fill(0.0);
            }
        }
        for &u in &sparse.written {
            sparse.marked[u] = false;
        }
        sparse.written.clear();
        // The reach, and the input's planar copy on the reached units alone.
        self.load_sparse_input(&mut sparse, delta, spans);
        let reach = self.reach.as_ref().expect("apply_delta sets the reach");
        self.blocks_projected += reach.blocks.iter().filter(|r| **r).count();
        // What is written: MRT's blocks, marked here (MRT skips the others); the delta entries'
        // and the gather's rows, marked by those stages as they scatter.
        // Written: the reached blocks and the blocks transport carries their light into (what
        // `Runtime::block_written` says of each block, found from the reached blocks alone
        // rather than by a pass over every block's entries), marked in ascending order.
        let mut written = std::mem::take(&mut sparse.blocks_written);
        written.clear();
        for &u in sparse.reached.iter().filter(|&&u| u < sparse.n_blocks) {
            written.push(u as u32);
            written.extend_from_slice(sparse.targets_of(u));
        }
        written.sort_unstable();
        written.dedup();
        for &k in &written {
            sparse.mark(k as usize);
        }
        debug_assert!((0..self.blocks.len()).all(|k| {
            let slots = &self.blocks[k];
            let targeting = &self.entry_order[slots.entries_start..slots.entries_end];
            let by_pass = Runtime::block_written(
                self.reach.as_ref(),
                self.bundle.transport.as_ref(),
                targeting,
                k,
            );
            by_pass == written.binary_search(&(k as u32)).is_ok()
        }));
        sparse.blocks_written = written;
        sparse.active = true;
        self.sparse = Some(sparse);

        self.project_blocks(delta);
        self.mrt_albedo_free(change);
        if method == Method::Drt {
            self.drop_replaced(change);
            self.project_clutter();
            self.add_drt_deltas(change);
            self.add_direct_gather(delta, change);
        }

        let mut sparse = self.sparse.take().expect("set above");
        sparse.active = false;
        let albedo = &self.bundle.layout.albedo;
        for &u in &sparse.written {
            let r = sparse.ranges[u].clone();
            let rho = albedo[r.clone()].as_flattened();
            for (o, rho) in change[r].as_flattened_mut().iter_mut().zip(rho) {
                *o *= rho;
            }
        }
        self.sparse = Some(sparse);
    }
}

/// Calls `f(unit, texels)` for each piece of `spans` (clipped to the first `n` texels) within
/// one unit, in span order: the units of `unit_of`, their texel `ranges`.
fn for_each_unit_in(
    unit_of: &[u32],
    ranges: &[Range<usize>],
    spans: &[Range<usize>],
    n: usize,
    mut f: impl FnMut(usize, Range<usize>),
) {
    for span in spans {
        let (mut t, end) = (span.start.min(n), span.end.min(n));
        while t < end {
            let u = unit_of[t] as usize;
            let stop = ranges[u].end.min(end);
            f(u, t..stop);
            t = stop;
        }
    }
}

/// Per source block, the blocks the bundle's transport entries carry its light into: `(targets,
/// target_start)` in the layout of [`Sparse::targets`].
fn transport_targets(rt: &Runtime) -> (Vec<u32>, Vec<u32>) {
    let n = rt.blocks.len();
    let mut pairs: Vec<(u32, u32)> = Vec::new();
    for (k, slots) in rt.blocks.iter().enumerate() {
        for &i in &rt.entry_order[slots.entries_start..slots.entries_end] {
            let i = i as usize;
            match rt.bundle.transport.as_ref() {
                Some(TransportOps::Traced(e)) => pairs.push((e[i].source_block, k as u32)),
                Some(TransportOps::Lightfield(e)) => pairs.push((e[i].source_block, k as u32)),
                Some(TransportOps::Compact(e)) => {
                    pairs.extend(e[i].sources.iter().map(|&s| (s, k as u32)))
                }
                Some(TransportOps::Factored(_)) => {
                    unreachable!("kind 3 is unfolded at load (Runtime::try_new)")
                }
                None => {}
            }
        }
    }
    grouped_by_key(pairs, n)
}

/// `(key, value)` pairs with keys below `n` as lists per key: `(values, start)`, key `k`'s
/// values `values[start[k] .. start[k + 1]]` ascending, each once.
fn grouped_by_key(mut pairs: Vec<(u32, u32)>, n: usize) -> (Vec<u32>, Vec<u32>) {
    pairs.sort_unstable();
    pairs.dedup();
    let mut start = vec![0u32; n + 1];
    for &(k, _) in &pairs {
        start[k as usize + 1] += 1;
    }
    for k in 0..n {
        start[k + 1] += start[k];
    }
    (pairs.into_iter().map(|(_, v)| v).collect(), start)
}

/// Per list of texels (`lists`), the units of `unit_of` (`n_units` of them) its texels lie
/// in, each once in the order the texels first reach them: `(units, start)`, list `i`'s
/// `units[start[i] .. start[i + 1]]`.
pub(super) fn units_of_rows<'a>(
    lists: impl Iterator<Item = &'a [u32]>,
    unit_of: &[u32],
    n_units: usize,
) -> (Vec<u32>, Vec<u32>) {
    let (mut units, mut start) = (Vec::new(), vec![0u32]);
    let mut seen = vec![u32::MAX; n_units];
    for (i, texels) in lists.enumerate() {
        for &t in texels {
            let u = unit_of[t as usize];
            if std::mem::replace(&mut seen[u as usize], i as u32) != i as u32 {
                units.push(u);
            }
        }
        start.push(units.len() as u32);
    }
    (units, start)
}

/// Per unit (of `unit_of`, the sparse state's), the DRT delta entries whose source reads it:
/// `(entries, start)` in the layout of [`Sparse::unit_entries`].
fn delta_entries_by_unit(rt: &Runtime, n_blocks: usize, unit_of: &[u32]) -> (Vec<u32>, Vec<u32>) {
    let n_units = unit_of
        .iter()
        .map(|&u| u as usize + 1)
        .max()
        .unwrap_or(0)
        .max(n_blocks);
    let mut pairs: Vec<(u32, u32)> = Vec::new();
    for (i, e) in rt
        .bundle
        .drt
        .iter()
        .flat_map(|d| d.entries.iter())
        .enumerate()
    {
        match e.source {
            DeltaSource::Block(k) => pairs.push((k, i as u32)),
            DeltaSource::Clutter(j) => pairs.push((n_blocks as u32 + j, i as u32)),
            DeltaSource::Direct { first, count } => {
                let (first, count) = (first as usize, count as usize);
                let end = (first + count).min(unit_of.len());
                pairs.extend(unit_of[first.min(end)..end].iter().map(|&u| (u, i as u32)));
            }
        }
    }
    let n_units = pairs
        .iter()
        .map(|p| p.0 as usize + 1)
        .fold(n_units, usize::max);
    grouped_by_key(pairs, n_units)
}
