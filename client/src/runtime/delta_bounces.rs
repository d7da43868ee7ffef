//! Bounces of a change that follow it: [`Runtime::apply_delta`] with `Fixed(n)` (n ≥ 2) and
//! `Converged` sums the change's light bounce by bounce, each bounce the one-bounce sparse
//! application (module `incremental`) of the bounce before, so the work goes where the
//! change's light goes, one transport hop a bounce, and stops where that light no longer
//! matters.
//!
//! - `Fixed(n)`: n sparse applications, summed: the same as the full-size path to float
//!   rounding.
//! - `Converged { tolerance }`: bounce k's light `y_k = A r_{k−1}` (`r_0` the change of direct
//!   light) is added whole to the sum `x`. The next bounce's input `r_k` is `y_k` without its
//!   faintest units (blocks, clutter objects, the other texel runs), dropped faintest first
//!   while the light they would have made over every later bounce stays within half of what
//!   is left of the truncation budget (half the tolerance). The chain stops when the light of
//!   the bounces not made, plus what truncation dropped, is estimated within the tolerance of
//!   `x`'s own light.
//! - Light is measured in L1 (the sum over texels and channels of `|value|`; a change is
//!   signed). The gain `g` is the largest ratio, from the second bounce on, of a bounce's light
//!   to the light fed to it (at least [`MIN_GAIN`]); light `e` fed to a bounce makes about
//!   `e g / (1 − g)` over all the bounces after it. Like GMRES's, this is an estimate: the
//!   tolerance bounds the error relative to the change's indirect light, not the new light's.
//! - The chain gives up, and the caller runs the whole-level path, when it would cost more:
//!   before the first bounce (from the blocks the change touches and their transport
//!   targets; it starts only under [`START_MARGIN`] of the whole-level cost) and after every
//!   bounce (from the bounces made and the texels the last one wrote, times the bounces still
//!   to make), in full one-bounce applications. A chain bounce costs [`CHAIN_TEXEL_COST`]
//!   times the share of the level it writes; the bounces still to make follow from the tail
//!   estimate (before the second bounce, from the gain of the last whole-level solve). The
//!   whole-level path costs `Fixed(n)`'s n applications; for `Converged`, where its
//!   coefficient-space solve is made, [`COEFFICIENT_SOLVE_COST`] applications (MRT, module
//!   `reduced`) or [`COEFFICIENT_EXPANSION_COST`] plus half the chain's expected bounces at
//!   the share of a texel application's values each reads (DRT, module `reduced_drt`), else
//!   GMRES: [`GMRES_COST_PER_BOUNCE`] times the chain's expected bounces. It also gives up
//!   when the gain reaches the refusal gain (the whole-level path then refuses) or after
//!   [`MAX_BOUNCES`] bounces. Only time is lost: `out` is untouched until the end.
//!
//! Measured (2026-11-29, frame-time, one light moving, `Converged` 1e-3, one thread):
//! grid1000's light 0, 16 bounces over about 4,000 texels each, 4.5 ms against 40 ms; a
//! generated 320-block level's light 4, 8.8 ms against 32–43 ms; the maze's light fills most
//! of it and keeps the coefficient-space solve.
//!
//! Units: the change's light per texel (RGB radiance), as in `apply`; energies are f64 sums.
//!
//! Invariants: bounces run on the calling thread in a fixed order, truncation decides by
//! energies summed in unit order with ties broken by unit index, so results are deterministic
//! and bit-identical at any thread count. Nothing allocates after the first call of a runtime
//! but the lists of units (kept across calls, grown only when a call reaches more units).

use std::ops::Range;

use super::{Applied, ApplyError, Bounces, Method, Runtime, MAX_BOUNCES, MAX_CONVERGING_GAIN};

/// A chain bounce's cost, in full one-bounce applications, per share of the level's texels it
/// writes (its sparse bookkeeping and the transport into the written blocks). A rough figure,
/// set from a generated 80-block level's lights, the chain and the whole-level path timed side
/// by side (light 3: 10.6 ms against 17.5 ms; light 5 fills the level and is not tried).
pub(super) const CHAIN_TEXEL_COST: f64 = 2.0;

/// MRT's `Converged` by its coefficient-space solve, in full one-bounce applications (the
/// projection, the solve and one expansion).
pub(super) const COEFFICIENT_SOLVE_COST: f64 = 2.0;

/// DRT's coefficient-space solve's projection and expansion, in full one-bounce applications
/// (its GMRES applications are counted by the values they read). The maze: 5.5 ms in all
/// against 3.4 ms for one application; a generated 320-block level: 35 ms against 7.3 ms.
pub(super) const COEFFICIENT_EXPANSION_COST: f64 = 1.2;

/// `Converged` by GMRES over texels, in full one-bounce applications per bounce the chain
/// would make (GMRES needs about half the applications, each with its vector work; 80 blocks:
/// 16.7 ms against 1.3 ms for one application).
pub(super) const GMRES_COST_PER_BOUNCE: f64 = 0.75;

/// The chain starts only when its predicted cost is under this share of the whole-level
/// path's: a chain that gives up late has cost up to that path's time on top of it (a
/// generated 320-block level's light 19: 49 ms against 35 ms, started at a predicted 88%).
pub(super) const START_MARGIN: f64 = 0.75;

/// The gain the chain assumes before it has measured one, when no whole-level solve has.
pub(super) const ASSUMED_GAIN: f64 = 0.65;

/// The least gain the chain's light estimate assumes (a bounce that kept less light than this
/// of the light fed to it is estimated as keeping this much).
pub(super) const MIN_GAIN: f64 = 0.3;

/// The chain's state, kept between calls so that no call allocates.
#[derive(Clone, Debug)]
pub(super) struct Chain {
    /// The change's indirect light summed over the bounces made; non-zero on `sum_units` only,
    /// each listed once (`summed` while listed), with each unit's L1 light in `sum_energy`.
    sum: Vec<[f32; 3]>,
    sum_units: Vec<usize>,
    summed: Vec<bool>,
    sum_energy: Vec<f64>,
    /// The next bounce's input; non-zero on `input_units` only, whose texel ranges are
    /// `spans`.
    input: Vec<[f32; 3]>,
    input_units: Vec<usize>,
    spans: Vec<Range<usize>>,
    /// Scratch: (L1 light, unit) of the last bounce's units.
    order: Vec<(f64, usize)>,
    /// Whether the last `apply_delta` answered by the chain (its written units are `sum_units`).
    pub(super) answered: bool,
    /// Whether the chain runs whatever it costs (tests).
    unlimited: bool,
}

impl Chain {
    fn new(n_texels: usize, n_units: usize) -> Chain {
        Chain {
            sum: vec![[0.0; 3]; n_texels],
            sum_units: Vec::new(),
            summed: vec![false; n_units],
            sum_energy: vec![0.0; n_units],
            input: vec![[0.0; 3]; n_texels],
            input_units: Vec::new(),
            spans: Vec::new(),
            order: Vec::new(),
            answered: false,
            unlimited: false,
        }
    }

    /// The units the last chain's sum may be non-zero on.
    pub(super) fn sum_units(&self) -> &[usize] {
        &self.sum_units
    }

    /// The last chain's sum of the change's light over its bounces.
    pub(super) fn sum(&self) -> &[[f32; 3]] {
        &self.sum
    }

    /// Zeroes the sum and the input where the last call left them.
    fn clear(&mut self, ranges: &[Range<usize>]) {
        for &u in &self.sum_units {
            self.sum[ranges[u].clone()].as_flattened_mut().fill(0.0);
            self.summed[u] = false;
            self.sum_energy[u] = 0.0;
        }
        self.sum_units.clear();
        self.clear_input(ranges);
    }

    fn clear_input(&mut self, ranges: &[Range<usize>]) {
        for &u in &self.input_units {
            self.input[ranges[u].clone()].as_flattened_mut().fill(0.0);
        }
        self.input_units.clear();
        self.spans.clear();
    }

    /// Adds `y` on unit `u` (texels `r`) to the sum; returns (L1 light of `y` there, the
    /// change of the sum's L1 light).
    fn add(&mut self, u: usize, r: Range<usize>, y: &[[f32; 3]]) -> (f64, f64) {
        if !self.summed[u] {
            self.summed[u] = true;
            self.sum_units.push(u);
        }
        let (mut e_y, mut e_sum) = (0.0f64, 0.0f64);
        for (s, v) in self.sum[r.clone()].iter_mut().zip(&y[r]) {
            for c in 0..3 {
                s[c] += v[c];
                e_y += v[c].abs() as f64;
                e_sum += s[c].abs() as f64;
            }
        }
        let change = e_sum - self.sum_energy[u];
        self.sum_energy[u] = e_sum;
        (e_y, change)
    }
}

impl Runtime {
    /// The gain of light from one bounce to the next assumed before one is measured: the last
    /// whole-level solve's (`WarmStart::solved_gain`) where it is plausible, else
    /// [`ASSUMED_GAIN`]. The chain's estimate before its second bounce, and the one feedback
    /// by the change (module `delta_feedback`) judges unshot light by.
    pub(super) fn assumed_gain(&self) -> f64 {
        let solved = self.warm.solved_gain();
        if solved > 0.05 && solved < MAX_CONVERGING_GAIN {
            solved
        } else {
            ASSUMED_GAIN
        }
    }

    /// Relights by the change over `bounces` (`Fixed(n ≥ 2)` or `Converged`) bounce by bounce
    /// (module doc): `y` is the one-bounce sparse output's buffer (the runtime's `delta_out`),
    /// and the sum is left in the chain (`Chain::sum` on `Chain::sum_units`). None when the chain
    /// gave up (the caller then takes the full-size path; `y` is then garbage).
    pub(super) fn apply_chain(
        &mut self,
        method: Method,
        bounces: Bounces,
        delta: &[[f32; 3]],
        spans: Option<&[Range<usize>]>,
        y: &mut [[f32; 3]],
    ) -> Option<Result<Applied, ApplyError>> {
        let (limit, tolerance) = match bounces {
            Bounces::Fixed(n) => (n, None),
            Bounces::Converged { tolerance } => (MAX_BOUNCES, Some(tolerance as f64)),
            _ => unreachable!("the chain sums Fixed and Converged"),
        };
        self.prepare_delta();
        let n_units = self.sparse_ranges().len();
        let mut chain = self
            .chain
            .take()
            .unwrap_or_else(|| Chain::new(self.n_texels, n_units));
        chain.answered = false;
        chain.clear(self.sparse_ranges());
        let result = self.run_chain(method, limit, tolerance, delta, spans, y, &mut chain);
        chain.answered = matches!(result, Some(Ok(_)));
        self.chain = Some(chain);
        result
    }

    /// Lets the chain run whatever it reads (the hand-built test bundles are so small that
    /// every change's light fills them).
    #[cfg(test)]
    pub(super) fn let_the_chain_run(&mut self) {
        self.prepare_delta();
        let (n, n_units) = (self.n_texels, self.sparse_ranges().len());
        let chain = self.chain.get_or_insert_with(|| Chain::new(n, n_units));
        chain.unlimited = true;
    }

    /// Whether the last [`Runtime::apply_delta`] answered by the chain.
    #[cfg(test)]
    pub(super) fn answered_by_chain(&self) -> bool {
        self.chain.as_ref().is_some_and(|c| c.answered)
    }

    #[allow(clippy::too_many_arguments)]
    fn run_chain(
        &mut self,
        method: Method,
        limit: u32,
        tolerance: Option<f64>,
        delta: &[[f32; 3]],
        spans: Option<&[Range<usize>]>,
        y: &mut [[f32; 3]],
        chain: &mut Chain,
    ) -> Option<Result<Applied, ApplyError>> {
        let n = self.n_texels as f64;
        // The whole-level path's cost and the bounces the chain expects (module doc).
        let assumed = self.assumed_gain();
        let (expected, whole_level) = match tolerance {
            None => (limit as f64, limit as f64),
            Some(tolerance) => {
                let expected = ((0.5 * tolerance).ln() / assumed.ln()).clamp(2.0, 100.0);
                // DRT's coefficient solve: the projection and the expansion, then GMRES's
                // applications (about half the chain's bounces) at the share of a texel
                // application's values each reads.
                let coefficients = match method {
                    Method::Mrt => self.reduced.is_some().then_some(COEFFICIENT_SOLVE_COST),
                    Method::Drt => self
                        .reduced_drt
                        .as_ref()
                        .map(|r| COEFFICIENT_EXPANSION_COST + 0.5 * expected * r.read_share),
                    Method::Full => None,
                };
                (
                    expected,
                    coefficients.unwrap_or(GMRES_COST_PER_BOUNCE * expected),
                )
            }
        };
        let unlimited = chain.unlimited;
        let too_dear = |made: f64, written: f64, to_make: f64, margin: f64| {
            !unlimited && made + CHAIN_TEXEL_COST * written / n * to_make > margin * whole_level
        };
        if let Some(spans) = spans {
            // What the first bounce will write, known from the spans alone.
            let sparse = self.sparse.as_mut().expect("prepare_delta made it");
            let first = sparse.spread_texels(spans) as f64;
            if too_dear(0.0, first, expected, START_MARGIN) {
                return None;
            }
        }
        let (mut made, mut gain, mut fed, mut spent, mut sum_light) =
            (0.0f64, 0.0f64, 0.0, 0.0, 0.0);
        for bounce in 1..=limit {
            if bounce == 1 {
                self.apply_once_sparse(method, delta, spans, y);
            } else {
                self.apply_once_sparse(method, &chain.input, Some(&chain.spans), y);
            }
            let sparse = self
                .sparse
                .as_ref()
                .expect("the sparse application made it");
            // The bounce's light into the sum, unit by unit.
            chain.order.clear();
            let (mut light, mut written) = (0.0f64, 0usize);
            for &u in sparse.written() {
                let r = sparse.ranges()[u].clone();
                written += r.len();
                let (e, change) = chain.add(u, r, y);
                sum_light += change;
                light += e;
                chain.order.push((e, u));
            }
            if !light.is_finite() || !sum_light.is_finite() {
                return Some(Err(ApplyError::NonFinite { bounce }));
            }
            if bounce > 1 && fed > 0.0 {
                gain = gain.max(light / fed);
            }
            if tolerance.is_some() && gain >= MAX_CONVERGING_GAIN {
                return None;
            }
            let g = gain.max(MIN_GAIN);
            let later = g / (1.0 - g);
            let mut keep_above = (f64::NEG_INFINITY, 0usize);
            if let Some(tolerance) = tolerance {
                let allowed = tolerance * sum_light;
                if light == 0.0 || (bounce > 1 && spent + light * later <= allowed) {
                    return Some(Ok(Applied {
                        bounces: bounce,
                        remaining_fraction: if sum_light > 0.0 {
                            ((spent + light * later) / sum_light) as f32
                        } else {
                            0.0
                        },
                    }));
                }
                if bounce > 1 {
                    // Drop the faintest units while their later light fits half of what is
                    // left of the truncation budget.
                    let mut may_drop = ((0.5 * allowed - spent) * 0.5).max(0.0) / later;
                    chain
                        .order
                        .sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                    for &(e, u) in &chain.order {
                        if e > may_drop {
                            break;
                        }
                        may_drop -= e;
                        spent += e * later;
                        keep_above = (e, u);
                    }
                }
            } else if bounce == limit {
                return Some(Ok(Applied {
                    bounces: bounce,
                    remaining_fraction: 0.0,
                }));
            }
            if bounce == limit {
                return None;
            }
            // The bounces still to make: until the tail fits half the tolerance.
            made += CHAIN_TEXEL_COST * written as f64 / n;
            let to_make = match tolerance {
                None => (limit - bounce) as f64,
                Some(_) if bounce == 1 => expected - 1.0,
                Some(tolerance) => {
                    let fits = 0.5 * tolerance * sum_light / (light * later);
                    (fits.ln() / g.ln()).max(1.0)
                }
            };
            if too_dear(made, written as f64, to_make, 1.0) {
                return None;
            }
            // The next bounce's input: this bounce's light on the units kept, ascending.
            chain.clear_input(sparse.ranges());
            fed = 0.0;
            for &(e, u) in &chain.order {
                if (e, u) > keep_above {
                    chain.input_units.push(u);
                    fed += e;
                }
            }
            chain.input_units.sort_unstable();
            for &u in &chain.input_units {
                let r = sparse.ranges()[u].clone();
                chain.input[r.clone()].copy_from_slice(&y[r.clone()]);
                chain.spans.push(r);
            }
        }
        None
    }
}
