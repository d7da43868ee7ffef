//! [`Bounces::Warm`](super::Bounces::Warm): all bounces to a tolerance, starting from the
//! previous answer.
//!
//! The all-bounce indirect light `x` of direct light `L` solves `x = A (L + x)` (module doc of
//! [`super`]). Given a guess `x0` — the last all-bounce answer of the same method (the previous
//! frame's), moved on by its last change when the frame before was solved for other light
//! (`2 x_{t−1} − x_{t−2}`: a light moving steadily leaves a residual of second order in its
//! step; after a frame of still light, the answer itself) — one application gives `w = A (L + x0)` and with it the residual
//! `r0 = w − x0` of `x0` in `(I − A) x = A L`. The error of `x0` is `(I − A)⁻¹ r0`, about
//! `‖r0‖ / (1 − g)` with `g` the operator's gain (its spectral radius, the fraction of energy a
//! late bounce keeps). So:
//! - when `‖r0‖ ≤ tolerance · (1 − g) · ‖w‖` in every channel, `w` is the answer, after one
//!   application (the cost of [`Bounces::Feedback`](super::Bounces::Feedback)); it is one more
//!   bounce on `x0`, so its error is `A` times `x0`'s, smaller still;
//! - otherwise restarted GMRES ([`super::krylov`]) solves `(I − A) δ = r0` to the residual the
//!   tolerance asks, with a margin of 2 (relative to `r0`: `tolerance · (1 − g) · ‖w‖ / (2 ‖r0‖)`;
//!   the margin lets the next still frame pass the check at one application) and the answer is
//!   `x0 + δ`, kept when its residual is within the tolerance of its own light too (a light
//!   switched off leaves a small answer, which the guess's scale would misjudge; that case, and
//!   a stalled solve, solve cold). A light that moved a little leaves a small `r0` and costs a
//!   few applications; a jump costs about a cold solve.
//!
//! This is the same stopping rule as [`Bounces::Converged`](super::Bounces::Converged)'s, whose
//! GMRES stops at `‖r‖ ≤ tolerance · ‖A L‖` with `‖A L‖ ≈ (1 − g) ‖x‖`: the guess decides the
//! cost, never the accuracy.
//!
//! Units: RGB radiance per texel, as everywhere in the runtime; norms are per channel, f64.
//!
//! Invariants:
//! - `g` comes from the method's last cold solve (the Ritz estimate of its first Arnoldi cycle,
//!   a property of the operator, not of the light), raised by later estimates and never
//!   lowered; without a previous answer of the same method the call is a cold `Converged`
//!   solve, and so is any warm solve that stalls.
//! - The answer depends on the guess (within the tolerance), so on the calls before; for the
//!   same sequence of calls it is bit-identical at any thread count. An error forgets the guess.
//! - No allocation: the last two answers and the guess have their own buffers (36 bytes a
//!   texel); the residual and `δ` use the runtime's bounce scratch.

use super::krylov::{norm, Unsolved};
use super::{Applied, ApplyError, Method, Runtime, MAX_BOUNCES, MAX_CONVERGING_GAIN};

/// The guess [`Bounces::Warm`](super::Bounces::Warm) starts from.
#[derive(Clone, Debug)]
pub(super) struct WarmStart {
    /// The last all-bounce answer (`Converged` or `Warm`), per texel.
    answer: Vec<[f32; 3]>,
    /// The answer before it, when it was made with the same method for other direct light
    /// (`has_previous`: the light moved between the two).
    previous: Vec<[f32; 3]>,
    has_previous: bool,
    /// Fingerprint of the direct light `answer` was made for.
    light: u64,
    /// The guess of the current call when extrapolated from `previous` (`extrapolated`; else
    /// the guess is `answer` itself).
    guess: Vec<[f32; 3]>,
    extrapolated: bool,
    /// The method `answer` was made with; None: no guess.
    method: Option<Method>,
    /// The operator's gain for `method`.
    gain: f64,
    /// The gain the solve of the current call estimated (kept by `remember`).
    solved_gain: f64,
}

impl WarmStart {
    pub(super) fn new(n_texels: usize) -> WarmStart {
        WarmStart {
            answer: vec![[0.0; 3]; n_texels],
            previous: vec![[0.0; 3]; n_texels],
            has_previous: false,
            light: 0,
            guess: vec![[0.0; 3]; n_texels],
            extrapolated: false,
            method: None,
            gain: 0.0,
            solved_gain: 0.0,
        }
    }

    /// Drops the guess: the next `Warm` call solves cold.
    pub(super) fn forget(&mut self) {
        self.method = None;
        self.has_previous = false;
    }

    /// Makes the guess: the last answer moved on by its last change (`2 · answer −
    /// previous`, into `guess`), or the last answer itself when there is no previous one.
    fn predict(&mut self) {
        self.extrapolated = self.has_previous;
        if self.extrapolated {
            for ((g, a), p) in self.guess.iter_mut().zip(&self.answer).zip(&self.previous) {
                *g = std::array::from_fn(|c| 2.0 * a[c] - p[c]);
            }
        }
    }

    /// The guess [`WarmStart::predict`] made.
    fn guess(&self) -> &[[f32; 3]] {
        if self.extrapolated {
            &self.guess
        } else {
            &self.answer
        }
    }

    /// Records the gain a cold solve estimated (before [`Runtime::remember_answer`]).
    pub(super) fn solved(&mut self, gain: f64) {
        self.solved_gain = gain;
    }

    /// The operator's gain (spectral radius) estimated by the last cold solve (0 before one).
    pub(super) fn solved_gain(&self) -> f64 {
        self.solved_gain
    }

    /// Adds a change of indirect light to the guess (`apply_delta` moved the answer; the
    /// motion before it is forgotten).
    pub(super) fn add_change(&mut self, method: Method, change: &[[f32; 3]]) {
        let n = change.len();
        self.add_change_in(method, change, std::iter::once(0..n));
    }

    /// [`WarmStart::add_change`] of a change that is zero outside `spans`.
    pub(super) fn add_change_in(
        &mut self,
        method: Method,
        change: &[[f32; 3]],
        spans: impl Iterator<Item = std::ops::Range<usize>>,
    ) {
        if self.method == Some(method) {
            self.has_previous = false;
            for r in spans {
                let d = change[r.clone()].as_flattened();
                for (a, d) in self.answer[r].as_flattened_mut().iter_mut().zip(d) {
                    *a += d;
                }
            }
        }
    }
}

/// A 64-bit fingerprint of a light vector's bits (equal lights, equal fingerprints; a
/// collision would only cost a worse guess). One lane per channel, so the three multiply
/// chains run side by side (it is on every `Warm` frame's path).
fn fingerprint(light: &[[f32; 3]]) -> u64 {
    let mut h = [0x9e37_79b9_7f4a_7c15u64 ^ light.len() as u64; 3];
    for v in light {
        for c in 0..3 {
            h[c] = (h[c] ^ v[c].to_bits() as u64).wrapping_mul(0x0100_0000_01b3);
            h[c] ^= h[c] >> 29;
        }
    }
    (h[0] ^ h[1].rotate_left(21) ^ h[2].rotate_left(42)).wrapping_mul(0x0100_0000_01b3)
}

impl Runtime {
    /// After a `Converged` or `Warm` call: keeps its answer as the next `Warm` call's guess,
    /// or forgets the guess on an error. A change of light (`apply_delta`) is not an answer.
    pub(super) fn remember_answer(
        &mut self,
        method: Method,
        direct: &[[f32; 3]],
        out: &[[f32; 3]],
        result: &Result<Applied, ApplyError>,
    ) {
        if self.by_change {
            return;
        }
        let warm = &mut self.warm;
        if result.is_ok() {
            // Only a move of the light is extrapolated, not the solver's own corrections of
            // the answer for a light that held still.
            let light = fingerprint(direct);
            warm.has_previous = warm.method == Some(method) && light != warm.light;
            warm.light = light;
            std::mem::swap(&mut warm.previous, &mut warm.answer);
            warm.answer.copy_from_slice(out);
            warm.method = Some(method);
            warm.gain = warm.solved_gain;
        } else {
            warm.forget();
        }
    }

    /// [`Bounces::Warm`](super::Bounces::Warm) (module doc): `out` is all bounces of `direct`
    /// to `tolerance`, from the previous answer when there is one.
    pub(super) fn converge_warm(
        &mut self,
        method: Method,
        direct: &[[f32; 3]],
        out: &mut [[f32; 3]],
        tolerance: f32,
    ) -> Result<Applied, ApplyError> {
        if self.warm.method != Some(method) || self.by_change {
            return self.converge(method, direct, out, tolerance);
        }
        let gain = self.warm.gain;
        let scale = 1.0 - gain;
        self.warm.predict();
        // w = A (L + x0), then r0 = w − x0 (in `residual`).
        let mut residual = std::mem::take(&mut self.bounce_in);
        for ((l, d), x0) in residual.iter_mut().zip(direct).zip(self.warm.guess()) {
            *l = [d[0] + x0[0], d[1] + x0[1], d[2] + x0[2]];
        }
        self.apply_once(method, &residual, out);
        for ((r, w), x0) in residual.iter_mut().zip(out.iter()).zip(self.warm.guess()) {
            *r = [w[0] - x0[0], w[1] - x0[1], w[2] - x0[2]];
        }
        // A norm is finite exactly when every value is (f32 squares cannot overflow f64).
        let (r_norm, w_norm) = (norm(&residual), norm(out));
        if r_norm.iter().chain(&w_norm).any(|v| !v.is_finite()) {
            self.bounce_in = residual;
            return Err(ApplyError::NonFinite { bounce: 1 });
        }
        // Per channel: the estimated error of x0 relative to the light.
        let remaining: [f64; 3] = std::array::from_fn(|c| match (r_norm[c], w_norm[c]) {
            (r, _) if r == 0.0 => 0.0,
            (_, w) if w == 0.0 => f64::INFINITY,
            (r, w) => r / (scale * w),
        });
        let worst = remaining.iter().copied().fold(0.0, f64::max);
        if worst <= tolerance as f64 {
            self.bounce_in = residual;
            self.warm.solved(gain);
            return Ok(Applied {
                bounces: 1,
                remaining_fraction: worst as f32,
            });
        }
        if !worst.is_finite() {
            // No light left to measure against: solve cold.
            self.bounce_in = residual;
            return self.cold_after(method, direct, out, tolerance, 1);
        }
        // GMRES on the rest: the residual target relative to ‖r0‖, the tightest channel's,
        // with a margin of 2 so that the next frame, if the lights then hold still, passes
        // the check at one application.
        let target = remaining
            .iter()
            .filter(|&&e| e > 0.0)
            .map(|&e| 0.5 * tolerance as f64 / e)
            .fold(1.0, f64::min);
        let mut krylov = self.take_krylov();
        let mut delta = std::mem::take(&mut self.bounce_out);
        let solved = krylov.solve(
            &mut |v, w| self.apply_once(method, v, w),
            &residual,
            &mut delta,
            target,
            MAX_BOUNCES - 2,
        );
        self.krylov = Some(krylov);
        self.bounce_in = residual;
        let result = match solved {
            Ok(s) if s.gain.max(gain) < MAX_CONVERGING_GAIN => {
                for ((o, x0), d) in out.iter_mut().zip(self.warm.guess()).zip(&delta) {
                    *o = [x0[0] + d[0], x0[1] + d[1], x0[2] + d[2]];
                }
                // The rest measured against the answer's own light, not the guess's: light
                // that fell sharply (a light switched off) is solved cold instead.
                let x_norm = norm(out);
                let rest = (0..3)
                    .map(|c| match s.residual * r_norm[c] {
                        r if r == 0.0 => 0.0,
                        r => r / (scale * x_norm[c]),
                    })
                    .fold(0.0, f64::max);
                (rest <= tolerance as f64).then(|| {
                    self.warm.solved(gain.max(s.gain));
                    Ok(Applied {
                        bounces: 1 + s.applications,
                        remaining_fraction: rest as f32,
                    })
                })
            }
            Err(Unsolved::NonFinite { application }) => Some(Err(ApplyError::NonFinite {
                bounce: application + 1,
            })),
            // Stalled, or a gain the cold solve must judge: solve cold.
            _ => None,
        };
        self.bounce_out = delta;
        match result {
            Some(r) => r,
            None => self.cold_after(method, direct, out, tolerance, 1),
        }
    }

    /// A cold `Converged` solve after `spent` applications of a warm attempt (counted in).
    fn cold_after(
        &mut self,
        method: Method,
        direct: &[[f32; 3]],
        out: &mut [[f32; 3]],
        tolerance: f32,
        spent: u32,
    ) -> Result<Applied, ApplyError> {
        self.converge(method, direct, out, tolerance)
            .map(|a| Applied {
                bounces: a.bounces + spent,
                ..a
            })
    }
}
