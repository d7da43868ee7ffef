//! Feedback by the change ([`Runtime::apply_delta`] with [`Bounces::Feedback`]): all bounces
//! spread over frames, each frame one sparse application of the light not yet bounced, where
//! that light is. Progressive radiosity's shooting (Cohen et al. 1988) on the operators'
//! units: light added to the answer is "unshot" until it has been bounced once itself.
//!
//! A call with the change of direct light `Δ`:
//! 1. the input is `Δ` plus the unshot light of the units that are due; those units' unshot
//!    light is then zero. With a budget
//!    ([`Runtime::set_feedback_budget`]) the due units go most urgent first (by how far their
//!    unshot light passes their share of the tolerance) until their texels fill it, and the
//!    rest stay due;
//! 2. `y = A(input)` by the one-bounce sparse application (module `incremental`), added to the
//!    answer and to the unshot light where it was written;
//! 3. each unit written is due on the next call when its unshot light, over all the bounces it
//!    would still make, is over its share of the tolerance: `e g / (1 − g) > tol · s_u` (`e`
//!    the unit's unshot L1 light). Its share `s_u` is its own light in the last
//!    [`Runtime::apply`]'s answer, but at most its share of the level's light (`S n_u / n`:
//!    `S` that answer's L1 light, `n_u` the unit's texels, `n` the level's) and at least
//!    [`DIM_UNIT`] of it. Before any `apply`, the light is what feedback by the change has
//!    added (the L1 of every call's light summed per texel: the light itself when lights
//!    were switched on from darkness, more when they moved). A unit not written keeps its
//!    decision: neither its unshot light nor its light changed.
//!
//! What is never shot thus sums to at most the tolerance of the level's light, and a unit
//! dimmer than the level's mean holds at most the tolerance of its own light (down to
//! [`DIM_UNIT`] of the mean). The shares are the last `apply`'s: a room whose light left it
//! since is judged by its light then, capped at the level's mean.
//!
//! Every call's answer holds the change's first bounce exactly (as [`Bounces::One`] by the
//! change) and the later bounces of earlier changes as far as they have been shot; with the
//! lights still, calls shoot what is due until nothing is (about `ln(tol)/ln(g)` calls, each
//! over where the light still matters), and the answer is then the all-bounce answer within
//! the tolerance: what is never shot is at most each unit's share of it. Each call reports how
//! far its answer is estimated to lag behind all bounces ([`Runtime::feedback_lag`]: the
//! unshot light's later bounces over the level's light). Nothing is dropped: unshot light
//! waits in its unit until more light makes it due. A frame's cost is one sparse bounce over
//! the change and the due units, not the bounces to convergence: the whole-level
//! [`Bounces::Feedback`] (Enlighten's radiosity feedback) at the cost of where light moves.
//!
//! Units: the change's light per texel (RGB radiance), as in `apply`; energies are f64 L1 sums
//! (over texels and channels of `|value|`; a change is signed). The gain `g` is the chain's
//! assumed gain (`Runtime::assumed_gain`: the last whole-level `Converged` solve's, else
//! `delta_bounces::ASSUMED_GAIN`), at least `delta_bounces::MIN_GAIN`.
//!
//! Invariants: units are shot in ascending order and judged in the order written, so results
//! are deterministic and bit-identical at any thread count; nothing allocates after the first
//! call but the lists of units (grown only when a call reaches more units); a method change or
//! [`Runtime::reset_feedback`] forgets the unshot light (the answer is then taken as
//! converged).

use std::ops::Range;

use super::delta_bounces::MIN_GAIN;
use super::{Applied, Method, Runtime, DEFAULT_TOLERANCE};

/// The least share of the tolerance a unit is judged by, relative to its share of the
/// level's light (a unit lit under this fraction of the level's mean is judged as lit at it).
/// Units dimmer than the mean are judged by their own light, so a dim room's error stays
/// near the tolerance of its light. Measured with `frame-time --update one-light --bounces
/// feedback` on grid1000, settled at 1e-3, the worst surface lit at 1% of the mean or more
/// against all bounces: light 41 moving 5 mm a frame, 1.6e-2 when units were judged by the
/// level's mean alone, 3.6e-3 at 0.1, in the same time; light 0 moving 5 cm a frame,
/// 6.6e-3 at 0.1 and 1.8e-3 at 0.01, 0.99 ms of operators a frame either way.
const DIM_UNIT: f64 = 0.01;

/// The unshot light and the units due, kept between calls.
#[derive(Clone, Debug)]
pub(super) struct Progress {
    /// Per texel: light added to the answer and not yet bounced.
    unshot: Vec<[f32; 3]>,
    /// Per unit, its unshot light's L1 when last written or shot (summed as the light is
    /// added, so judging reads no texel), and their sum: what [`Runtime::feedback_lag`]
    /// estimates the lag from without a pass over the level.
    unit_unshot: Vec<f64>,
    unshot_total: f64,
    /// Units to shoot on the next call, each once (`is_due` while listed), and per unit how
    /// far its unshot light passed its share of the tolerance when last judged (`e g / (1 −
    /// g)` over `tol · s_u`; a listed unit judged since at 1 or under is no longer due).
    due: Vec<usize>,
    is_due: Vec<bool>,
    urgency: Vec<f64>,
    /// Scratch: (urgency, unit) of the due units, most urgent first, and the units whose
    /// unshot light this call shoots.
    order: Vec<(f64, usize)>,
    chosen: Vec<bool>,
    /// Texels of due units a call shoots at most besides the change's (None: every due unit).
    pub(super) budget: Option<usize>,
    /// This call's input (zero outside `input_units`), its units ascending and their texels.
    input: Vec<[f32; 3]>,
    input_units: Vec<usize>,
    in_input: Vec<bool>,
    spans: Vec<Range<usize>>,
    /// The method the unshot light was made with.
    method: Option<Method>,
    /// The tolerance of the answer once nothing is due (relative, L1).
    pub(super) tolerance: f32,
}

impl Progress {
    pub(super) fn new(n_texels: usize, n_units: usize) -> Progress {
        Progress {
            unshot: vec![[0.0; 3]; n_texels],
            unit_unshot: vec![0.0; n_units],
            unshot_total: 0.0,
            due: Vec::new(),
            is_due: vec![false; n_units],
            urgency: vec![0.0; n_units],
            order: Vec::new(),
            chosen: vec![false; n_units],
            budget: None,
            input: vec![[0.0; 3]; n_texels],
            input_units: Vec::new(),
            in_input: vec![false; n_units],
            spans: Vec::new(),
            method: None,
            tolerance: DEFAULT_TOLERANCE,
        }
    }

    /// Forgets the unshot light.
    pub(super) fn forget(&mut self) {
        self.unshot.fill([0.0; 3]);
        self.unit_unshot.fill(0.0);
        self.unshot_total = 0.0;
        for &u in &self.due {
            self.is_due[u] = false;
        }
        self.due.clear();
        self.method = None;
    }

    /// Units due on the next call.
    pub(super) fn due(&self) -> usize {
        self.due.iter().filter(|&&u| self.urgency[u] > 1.0).count()
    }

    fn push_input(&mut self, u: usize) {
        if !self.in_input[u] {
            self.in_input[u] = true;
            self.input_units.push(u);
        }
    }
}

impl Runtime {
    /// Step 1 and 2 of the module doc: shoots `delta` (zero outside `spans` when given) and the
    /// due units' unshot light into `y` (the one-bounce sparse output's buffer) and adds `y` to
    /// the unshot light. The caller adds `y` to the answer on the units written, then calls
    /// [`Runtime::judge_unshot`].
    pub(super) fn shoot_unshot(
        &mut self,
        method: Method,
        delta: &[[f32; 3]],
        spans: Option<&[Range<usize>]>,
        y: &mut [[f32; 3]],
    ) -> Applied {
        self.progress_mut();
        let mut p = self.progress.take().expect("progress_mut made it");
        if p.method != Some(method) {
            p.forget();
            p.method = Some(method);
        }
        let sparse = self.sparse.as_ref().expect("prepare_delta made it");
        let ranges = sparse.ranges();
        for &u in &p.input_units {
            p.input[ranges[u].clone()].fill([0.0; 3]);
            p.in_input[u] = false;
        }
        p.input_units.clear();
        // The units the change lies in, then the due ones.
        match spans {
            Some(spans) => sparse.units_in(spans, |u| p.push_input(u)),
            None => {
                for (u, r) in ranges.iter().enumerate() {
                    if super::incremental::Reach::any_light(delta, r.clone()) {
                        p.push_input(u);
                    }
                }
            }
        }
        // The due units, most urgent first within the budget; the rest stay due.
        p.order.clear();
        for i in 0..p.due.len() {
            let u = p.due[i];
            p.is_due[u] = false;
            if p.urgency[u] > 1.0 {
                p.order.push((p.urgency[u], u));
            }
        }
        p.due.clear();
        if p.budget.is_some() {
            p.order
                .sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        }
        let mut left = p.budget.unwrap_or(usize::MAX);
        for i in 0..p.order.len() {
            let u = p.order[i].1;
            let texels = ranges[u].len();
            // At least one unit a call, so the answer settles whatever the budget.
            if texels <= left || i == 0 {
                left = left.saturating_sub(texels);
                p.chosen[u] = true;
                p.push_input(u);
            } else {
                p.is_due[u] = true;
                p.due.push(u);
            }
        }
        p.input_units.sort_unstable();
        p.spans.clear();
        for &u in &p.input_units {
            let r = ranges[u].clone();
            if p.chosen[u] {
                p.chosen[u] = false;
                for t in r.clone() {
                    let (d, s) = (delta[t], p.unshot[t]);
                    p.input[t] = [d[0] + s[0], d[1] + s[1], d[2] + s[2]];
                }
                p.unshot[r.clone()].fill([0.0; 3]);
                p.unshot_total -= std::mem::take(&mut p.unit_unshot[u]);
            } else {
                p.input[r.clone()].copy_from_slice(&delta[r.clone()]);
            }
            p.spans.push(r);
        }
        self.apply_once_sparse(method, &p.input, Some(&p.spans), y);
        let sparse = self
            .sparse
            .as_ref()
            .expect("the sparse application made it");
        // Adds `y` to the unshot light and keeps each written unit's L1 (what judging reads).
        for &u in sparse.written() {
            let mut unshot = 0.0f64;
            for t in sparse.ranges()[u].clone() {
                let (s, v) = (&mut p.unshot[t], y[t]);
                *s = [s[0] + v[0], s[1] + v[1], s[2] + v[2]];
                unshot += s[0].abs() as f64 + s[1].abs() as f64 + s[2].abs() as f64;
            }
            p.unshot_total += unshot - std::mem::replace(&mut p.unit_unshot[u], unshot);
        }
        self.progress = Some(p);
        // The lag is known once this call's light is judged (`apply_delta_impl`).
        Applied {
            bounces: 1,
            remaining_fraction: 0.0,
        }
    }

    /// Step 3 of the module doc: `y` is this call's light (on the units written).
    pub(super) fn judge_unshot(&mut self, y: &[[f32; 3]]) {
        let g = self.assumed_gain().max(MIN_GAIN);
        let (Some(p), Some(sparse)) = (self.progress.as_mut(), self.sparse.as_ref()) else {
            return;
        };
        if !self.light_applied {
            // No `apply` yet: the level's light is the light feedback has added.
            for &u in sparse.written() {
                for t in sparse.ranges()[u].clone() {
                    let add = y[t][0].abs() + y[t][1].abs() + y[t][2].abs();
                    self.texel_light[t] += add;
                    self.level_light += add as f64;
                }
            }
        }
        let later = g / (1.0 - g);
        let tol = p.tolerance as f64;
        let per_texel = self.level_light / self.n_texels.max(1) as f64;
        for &u in sparse.written() {
            let r = sparse.ranges()[u].clone();
            let level = per_texel * r.len() as f64;
            let own: f64 = self.texel_light[r.clone()].iter().map(|&x| x as f64).sum();
            let share = level.min(own.max(DIM_UNIT * level));
            let e = p.unit_unshot[u] * later;
            p.urgency[u] = if share > 0.0 {
                e / (tol * share)
            } else if e > 0.0 {
                f64::INFINITY
            } else {
                0.0
            };
            if p.urgency[u] > 1.0 && !p.is_due[u] {
                p.is_due[u] = true;
                p.due.push(u);
            }
        }
    }

    /// The feedback state, made (with what relighting by the change needs,
    /// [`Runtime::prepare_delta`]) on first use.
    fn progress_mut(&mut self) -> &mut Progress {
        self.prepare_delta();
        let (n, n_units) = (self.n_texels, self.sparse_ranges().len());
        self.progress
            .get_or_insert_with(|| Progress::new(n, n_units))
    }

    /// Units whose unshot light is due on the next [`Runtime::apply_delta`] with
    /// [`Bounces::Feedback`](super::Bounces::Feedback): 0 when the answer holds all bounces
    /// within the tolerance ([`Runtime::set_feedback_tolerance`]); a game keeps calling with a
    /// zero change (which costs the due units alone) until then.
    pub fn feedback_due(&self) -> usize {
        self.progress.as_ref().map_or(0, Progress::due)
    }

    /// How far the answer of [`Runtime::apply_delta`] with
    /// [`Bounces::Feedback`](super::Bounces::Feedback) is estimated to lag behind all bounces,
    /// relative to the level's light (L1, the light the tolerance is relative to): the light
    /// not yet bounced, over all the bounces it would still make (`e g / (1 − g)`, `e` its L1
    /// light), over the level's. It is that call's [`Applied::remaining_fraction`]; 0 before
    /// any such call (and after [`Runtime::reset_feedback`]), at most the tolerance once
    /// nothing is due (each unit's unshot light is then within its share of it). An
    /// estimate, as the tolerance is: the gain is the assumed one, so on the tests' hand-made
    /// operators (gains of their own) it is 0.34 to 14 times the lag measured against 300
    /// bounces.
    pub fn feedback_lag(&self) -> f64 {
        let Some(p) = self.progress.as_ref() else {
            return 0.0;
        };
        let g = self.assumed_gain().max(MIN_GAIN);
        let lag = p.unshot_total.max(0.0) * g / (1.0 - g);
        if lag == 0.0 {
            0.0
        } else if self.level_light > 0.0 {
            lag / self.level_light
        } else {
            f64::INFINITY
        }
    }

    /// Caps the texels of due units one [`Runtime::apply_delta`] with
    /// [`Bounces::Feedback`](super::Bounces::Feedback) shoots besides the change's (the most
    /// urgent first, at least one unit a call; the rest wait for the next calls), so a frame's
    /// cost stays near the change's own while the later bounces arrive over more frames; None
    /// (the default) shoots every due unit.
    pub fn set_feedback_budget(&mut self, texels: Option<usize>) {
        self.progress_mut().budget = texels;
    }

    /// The tolerance, relative to the level's light, of the answer that
    /// [`Runtime::apply_delta`] with [`Bounces::Feedback`](super::Bounces::Feedback) settles
    /// to (default [`DEFAULT_TOLERANCE`]; the module doc of `delta_feedback`). Values outside
    /// (0, 1) are refused.
    pub fn set_feedback_tolerance(&mut self, tolerance: f32) -> Result<(), super::ApplyError> {
        if !(tolerance > 0.0 && tolerance < 1.0) {
            return Err(super::ApplyError::BadTolerance(tolerance));
        }
        self.progress_mut().tolerance = tolerance;
        Ok(())
    }
}
