//! All bounces by restarted GMRES: solves `(I − A) x = b` for the indirect light `x`, where `A`
//! is the one-bounce operator (radiance leaving texels → one-bounce indirect radiance leaving
//! them, RGB, albedo included) and `b = A L_d` the first bounce. Its solution is the Neumann
//! series `x = Σ_{k≥1} A^k L_d` whenever that converges (spectral radius below 1), reached in far
//! fewer applications of `A` than summing bounces one by one: each application of `A` extends a
//! Krylov space in which GMRES picks the combination with the smallest residual.
//!
//! The three channels are three independent systems (`A` never mixes channels: albedo and
//! operators are per channel), solved in lockstep: one application of `A` to an RGB vector
//! serves all three, and each channel keeps its own Arnoldi basis coefficients, Hessenberg
//! matrix and Givens rotations.
//!
//! Invariants:
//! - Deterministic: every inner product is an f64 sum in texel order, so the result is
//!   bit-identical whenever `A` is (at any thread count).
//! - Stops when every channel's residual (the Arnoldi estimate, exact up to rounding) `‖b − (I − A)x‖` is at most `tolerance · ‖b‖`: the
//!   error of `x` relative to `x` is then about the same (error and solution are both led by the
//!   slowest-decaying mode, each scaled by `1/(1 − λ)`).
//! - Allocation-free after [`Krylov::new`]; memory is `restart + 2` RGB texel vectors.
//! - Never loops forever: at most `max_applications` applications of `A`, and a restart cycle
//!   that does not reduce the residual ends the solve; the caller checks the solution's energy
//!   against the first bounce's (an operator of gain ≥ 1 has no all-bounce light, and GMRES
//!   would still find the solution of the linear system, which is then not the light).

/// Arnoldi steps per restart cycle.
pub(crate) const RESTART: usize = 12;

/// What a solve did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Solved {
    /// Applications of `A`.
    pub applications: u32,
    /// Largest channel residual relative to that channel's `‖b‖`.
    pub residual: f64,
    /// The largest channel's estimated spectral radius of `A` (see [`spectral_radius`]).
    pub gain: f64,
}

/// Why a solve stopped without reaching the tolerance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Unsolved {
    /// The residual stopped falling, the system is singular in the Krylov space, or the
    /// applications ran out.
    Stalled {
        applications: u32,
        residual: f64,
        gain: f64,
    },
    /// `A` returned a non-finite value at this application.
    NonFinite { application: u32 },
}

/// GMRES workspace for vectors of `n` RGB texels.
#[derive(Clone, Debug)]
pub(crate) struct Krylov {
    /// Orthonormal basis, `RESTART + 1` vectors (per channel).
    basis: Vec<Vec<[f32; 3]>>,
    /// The application scratch `w`.
    w: Vec<[f32; 3]>,
    /// Per channel: Hessenberg `h[i][j]` (row-major, `(RESTART + 1) × RESTART`), Givens
    /// cosines and sines, and the rotated right-hand side `g`.
    h: [Vec<f64>; 3],
    /// The first cycle's Hessenberg before rotation (for [`spectral_radius`]).
    h0: [Vec<f64>; 3],
    cs: [Vec<f64>; 3],
    sn: [Vec<f64>; 3],
    g: [Vec<f64>; 3],
}

/// The three channels' inner products in one pass (f64, in texel order).
fn dot(a: &[[f32; 3]], b: &[[f32; 3]]) -> [f64; 3] {
    let mut s = [0.0f64; 3];
    for (x, y) in a.iter().zip(b) {
        s[0] += x[0] as f64 * y[0] as f64;
        s[1] += x[1] as f64 * y[1] as f64;
        s[2] += x[2] as f64 * y[2] as f64;
    }
    s
}

/// The three channels' Euclidean norms.
pub(super) fn norm(a: &[[f32; 3]]) -> [f64; 3] {
    dot(a, a).map(f64::sqrt)
}

/// Spectral radius of the `k × k` matrix `I − H` (H upper Hessenberg, row stride [`RESTART`]):
/// the growth rate `‖M^t v‖^(1/t)` of power iteration over 400 steps (complex pairs included).
/// With `H` the Arnoldi matrix of `I − A`, `I − H` holds the Ritz values of `A`, whose extreme
/// ones the first Arnoldi steps find: for light (a non-negative `A`), the largest is the
/// fraction of energy each late bounce keeps.
fn spectral_radius(h: &[f64], k: usize) -> f64 {
    if k == 0 {
        return 0.0;
    }
    // On the stack: a frame allocates nothing.
    let mut v = [1.0f64; RESTART];
    let mut next = [0.0f64; RESTART];
    let (v, next) = (&mut v[..k], &mut next[..k]);
    let mut log_growth = 0.0f64;
    const STEPS: usize = 400;
    const BURN_IN: usize = 100;
    for step in 0..STEPS {
        for i in 0..k {
            let mut s = v[i];
            for j in i.saturating_sub(1)..k {
                s -= h[i * RESTART + j] * v[j];
            }
            next[i] = s;
        }
        let norm = next.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm == 0.0 || !norm.is_finite() {
            return if norm == 0.0 { 0.0 } else { f64::INFINITY };
        }
        if step >= BURN_IN {
            log_growth += norm.ln();
        }
        for (a, b) in v.iter_mut().zip(next.iter()) {
            *a = b / norm;
        }
    }
    (log_growth / (STEPS - BURN_IN) as f64).exp()
}

impl Krylov {
    /// The largest channel's [`spectral_radius`] from the first cycle's columns (per channel:
    /// those before its Krylov space was exhausted; none for a channel without light).
    fn gain(&self, dims: [usize; 3]) -> f64 {
        (0..3)
            .map(|c| spectral_radius(&self.h0[c], dims[c]))
            .fold(0.0, f64::max)
    }

    pub(crate) fn new(n: usize) -> Krylov {
        let per = || {
            [
                vec![0.0; (RESTART + 1) * RESTART],
                vec![0.0; (RESTART + 1) * RESTART],
                vec![0.0; (RESTART + 1) * RESTART],
            ]
        };
        let small = || {
            [
                vec![0.0; RESTART + 1],
                vec![0.0; RESTART + 1],
                vec![0.0; RESTART + 1],
            ]
        };
        Krylov {
            basis: (0..=RESTART).map(|_| vec![[0.0; 3]; n]).collect(),
            w: vec![[0.0; 3]; n],
            h: per(),
            h0: per(),
            cs: small(),
            sn: small(),
            g: small(),
        }
    }

    /// The number of texels this workspace was made for.
    pub(crate) fn len(&self) -> usize {
        self.w.len()
    }

    /// Solves `(I − A) x = b` per channel to `tolerance` (relative residual), starting from
    /// `x = 0`; `a(v, out)` writes `A v` to `out`.
    pub(crate) fn solve(
        &mut self,
        a: &mut dyn FnMut(&[[f32; 3]], &mut [[f32; 3]]),
        b: &[[f32; 3]],
        x: &mut [[f32; 3]],
        tolerance: f64,
        max_applications: u32,
    ) -> Result<Solved, Unsolved> {
        let n = b.len();
        debug_assert_eq!(n, self.len());
        x.fill([0.0; 3]);
        let b_norm = norm(b);
        let relative = |r: [f64; 3]| {
            (0..3)
                .map(|c| {
                    if b_norm[c] > 0.0 {
                        r[c] / b_norm[c]
                    } else {
                        0.0
                    }
                })
                .fold(0.0f64, f64::max)
        };
        // The first residual is b itself (x = 0).
        self.basis[0].copy_from_slice(b);
        let mut applications = 0u32;
        let mut last_cycle_residual = f64::INFINITY;
        // Per channel: first-cycle columns before its Krylov space was exhausted, and whether
        // it was.
        let mut dims = [0usize; 3];
        let mut exhausted: [bool; 3] = std::array::from_fn(|c| b_norm[c] == 0.0);
        loop {
            // Start a cycle from the residual in basis[0].
            let beta = norm(&self.basis[0]);
            let residual = relative(beta);
            if residual <= tolerance {
                return Ok(Solved {
                    applications,
                    residual,
                    gain: self.gain(dims),
                });
            }
            if residual >= 0.99 * last_cycle_residual || applications >= max_applications {
                return Err(Unsolved::Stalled {
                    applications,
                    residual,
                    gain: self.gain(dims),
                });
            }
            let first_cycle = last_cycle_residual == f64::INFINITY;
            last_cycle_residual = residual;
            let scale = beta.map(|b| if b > 0.0 { (1.0 / b) as f32 } else { 0.0 });
            for v in self.basis[0].iter_mut() {
                v[0] *= scale[0];
                v[1] *= scale[1];
                v[2] *= scale[2];
            }
            for c in 0..3 {
                self.g[c].fill(0.0);
                self.g[c][0] = beta[c];
            }
            let mut steps = 0;
            let mut converged = false;
            let mut last_residual = residual;
            for j in 0..RESTART {
                // w = (I − A) v_j.
                a(&self.basis[j], &mut self.w);
                applications += 1;
                if self.w.iter().flatten().any(|v| !v.is_finite()) {
                    return Err(Unsolved::NonFinite {
                        application: applications,
                    });
                }
                for (w, v) in self.w.iter_mut().zip(&self.basis[j]) {
                    for c in 0..3 {
                        w[c] = v[c] - w[c];
                    }
                }
                // Modified Gram-Schmidt against v_0 .. v_j, per channel.
                for i in 0..=j {
                    let hij = dot(&self.w, &self.basis[i]);
                    let h32 = hij.map(|h| h as f32);
                    for (w, v) in self.w.iter_mut().zip(&self.basis[i]) {
                        w[0] -= h32[0] * v[0];
                        w[1] -= h32[1] * v[1];
                        w[2] -= h32[2] * v[2];
                    }
                    for c in 0..3 {
                        self.h[c][i * RESTART + j] = hij[c];
                    }
                }
                let norm = norm(&self.w);
                // A channel whose Krylov space is exhausted (its solution is exact in it) gets a
                // zero vector: its later columns add nothing.
                let scale: [f32; 3] = std::array::from_fn(|c| {
                    if norm[c] > 1e-30 * beta[c].max(1e-300) {
                        (1.0 / norm[c]) as f32
                    } else {
                        0.0
                    }
                });
                for (v, w) in self.basis[j + 1].iter_mut().zip(&self.w) {
                    v[0] = w[0] * scale[0];
                    v[1] = w[1] * scale[1];
                    v[2] = w[2] * scale[2];
                }
                let mut r = [0.0f64; 3];
                let mut singular = false;
                for c in 0..3 {
                    if first_cycle && !exhausted[c] {
                        dims[c] += 1;
                        exhausted[c] = norm[c] <= 1e-30 * beta[c].max(1e-300);
                        for i in 0..=j {
                            self.h0[c][i * RESTART + j] = self.h[c][i * RESTART + j];
                        }
                        self.h0[c][(j + 1) * RESTART + j] = norm[c];
                    }
                    let (h, cs, sn, g) = (
                        &mut self.h[c],
                        &mut self.cs[c],
                        &mut self.sn[c],
                        &mut self.g[c],
                    );
                    h[(j + 1) * RESTART + j] = norm[c];
                    // Earlier rotations on column j.
                    for i in 0..j {
                        let (x0, x1) = (h[i * RESTART + j], h[(i + 1) * RESTART + j]);
                        h[i * RESTART + j] = cs[i] * x0 + sn[i] * x1;
                        h[(i + 1) * RESTART + j] = -sn[i] * x0 + cs[i] * x1;
                    }
                    // The rotation that zeroes h[j+1][j].
                    let (p, q) = (h[j * RESTART + j], h[(j + 1) * RESTART + j]);
                    let d = p.hypot(q);
                    // A zero pivot with light left to place: I − A is singular here.
                    singular |= d <= 1e-12 * beta[c] && g[j] != 0.0;
                    (cs[j], sn[j]) = if d > 0.0 { (p / d, q / d) } else { (1.0, 0.0) };
                    h[j * RESTART + j] = d;
                    h[(j + 1) * RESTART + j] = 0.0;
                    g[j + 1] = -sn[j] * g[j];
                    g[j] *= cs[j];
                    r[c] = g[j + 1].abs();
                }
                steps = j + 1;
                if singular {
                    return Err(Unsolved::Stalled {
                        applications,
                        residual,
                        gain: self.gain(dims),
                    });
                }
                last_residual = relative(r);
                if last_residual <= tolerance {
                    converged = true;
                    break;
                }
                if applications >= max_applications {
                    break;
                }
            }
            // x += V y with H y = g (upper triangular, `steps` columns), per channel.
            for c in 0..3 {
                let (h, g) = (&self.h[c], &mut self.g[c]);
                for i in (0..steps).rev() {
                    let mut s = g[i];
                    for k in i + 1..steps {
                        s -= h[i * RESTART + k] * g[k];
                    }
                    g[i] = if h[i * RESTART + i] != 0.0 {
                        s / h[i * RESTART + i]
                    } else {
                        0.0
                    };
                }
            }
            for (i, v) in self.basis[..steps].iter().enumerate() {
                let y: [f32; 3] = std::array::from_fn(|c| self.g[c][i] as f32);
                for (xt, vt) in x.iter_mut().zip(v) {
                    xt[0] += y[0] * vt[0];
                    xt[1] += y[1] * vt[1];
                    xt[2] += y[2] * vt[2];
                }
            }
            if converged {
                return Ok(Solved {
                    applications,
                    residual: last_residual,
                    gain: self.gain(dims),
                });
            }
            // The next cycle starts from the true residual b − (I − A)x (one application).
            a(x, &mut self.w);
            applications += 1;
            if self.w.iter().flatten().any(|v| !v.is_finite()) {
                return Err(Unsolved::NonFinite {
                    application: applications,
                });
            }
            for ((r, bt), (xt, wt)) in self.basis[0].iter_mut().zip(b).zip(x.iter().zip(&self.w)) {
                for c in 0..3 {
                    r[c] = bt[c] - xt[c] + wt[c];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An n × n operator per channel with non-negative entries and row sums `gain[c]`: mostly
    /// a chain (light passed to the neighbours, like blocks in a corridor: eigenvalues spread
    /// over (−gain, gain), the hard case for Krylov methods) plus a little random coupling.
    fn operator(n: usize, gain: [f64; 3], seed: u64) -> Vec<[Vec<f64>; 3]> {
        let mut state = seed;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut rows: Vec<[Vec<f64>; 3]> = (0..n)
            .map(|i| {
                std::array::from_fn(|_| {
                    (0..n)
                        .map(|j| {
                            0.02 * next() / n as f64 + if i.abs_diff(j) == 1 { 1.0 } else { 0.0 }
                        })
                        .collect()
                })
            })
            .collect();
        for row in &mut rows {
            for c in 0..3 {
                let s: f64 = row[c].iter().sum();
                row[c].iter_mut().for_each(|v| *v *= gain[c] / s);
            }
        }
        rows
    }

    fn apply(m: &[[Vec<f64>; 3]], v: &[[f32; 3]], out: &mut [[f32; 3]]) {
        for (o, row) in out.iter_mut().zip(m) {
            for c in 0..3 {
                o[c] = row[c]
                    .iter()
                    .zip(v)
                    .map(|(a, x)| a * x[c] as f64)
                    .sum::<f64>() as f32;
            }
        }
    }

    /// `Σ_{k≥1} A^k b0`... in f64 until the terms vanish: the truth GMRES must reach.
    fn series(m: &[[Vec<f64>; 3]], b: &[[f32; 3]]) -> Vec<[f64; 3]> {
        let n = b.len();
        let mut term: Vec<[f64; 3]> = b.iter().map(|v| v.map(|x| x as f64)).collect();
        let mut sum = term.clone();
        for _ in 0..5000 {
            let next: Vec<[f64; 3]> = (0..n)
                .map(|i| {
                    std::array::from_fn(|c| m[i][c].iter().zip(&term).map(|(a, x)| a * x[c]).sum())
                })
                .collect();
            for (s, t) in sum.iter_mut().zip(&next) {
                for c in 0..3 {
                    s[c] += t[c];
                }
            }
            term = next;
        }
        sum
    }

    #[test]
    fn solves_each_channel_to_its_tolerance_through_restarts() {
        // Channels of very different gain (0.3, 0.8, 0.97): one basis per channel, and the
        // slow one needs several restart cycles at 1e-6.
        let n = 60;
        let m = operator(n, [0.3, 0.8, 0.97], 3);
        let b: Vec<[f32; 3]> = (0..n)
            .map(|i| {
                [
                    (i % 7) as f32,
                    1.0 + (i % 3) as f32,
                    (i % 5 == 0) as u8 as f32,
                ]
            })
            .collect();
        let truth = series(&m, &b);
        let mut k = Krylov::new(n);
        let mut x = vec![[0.0f32; 3]; n];
        for tolerance in [1e-3, 1e-6] {
            let solved = k
                .solve(&mut |v, o| apply(&m, v, o), &b, &mut x, tolerance, 1000)
                .unwrap();
            assert!(solved.residual <= tolerance, "{solved:?}");
            for c in 0..3 {
                let num: f64 = x
                    .iter()
                    .zip(&truth)
                    .map(|(a, t)| (a[c] as f64 - t[c]).powi(2))
                    .sum();
                let den: f64 = truth.iter().map(|t| t[c] * t[c]).sum();
                let err = (num / den).sqrt();
                assert!(
                    err <= 3.0 * tolerance + 1e-6,
                    "channel {c}, tolerance {tolerance}: {err}"
                );
            }
            if tolerance == 1e-6 {
                assert!(
                    solved.applications as usize > RESTART,
                    "{solved:?}: restarted"
                );
            }
        }
    }

    #[test]
    fn a_singular_system_stalls_instead_of_looping() {
        // Gain exactly 1 (a closed white room): I − A is singular and b is not in its range.
        let n = 20;
        let m = operator(n, [1.0; 3], 9);
        let b: Vec<[f32; 3]> = (0..n).map(|i| [1.0 + (i % 3) as f32; 3]).collect();
        let mut x = vec![[0.0f32; 3]; n];
        let mut k = Krylov::new(n);
        match k.solve(&mut |v, o| apply(&m, v, o), &b, &mut x, 1e-6, 500) {
            Err(Unsolved::Stalled {
                applications, gain, ..
            }) => {
                assert!(applications <= 500);
                assert!((gain - 1.0).abs() < 0.02, "gain estimate {gain}");
            }
            Ok(s) => assert!((s.gain - 1.0).abs() < 0.02, "{s:?}: the caller refuses it"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn zero_light_is_solved_without_applications() {
        let m = operator(5, [0.5; 3], 1);
        let b = vec![[0.0f32; 3]; 5];
        let mut x = vec![[1.0f32; 3]; 5];
        let solved = Krylov::new(5)
            .solve(&mut |v, o| apply(&m, v, o), &b, &mut x, 1e-3, 100)
            .unwrap();
        assert_eq!(solved.applications, 0);
        assert!(x.iter().flatten().all(|&v| v == 0.0));
    }
}
