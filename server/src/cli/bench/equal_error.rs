//! The reference path tracer as a peer "at equal error": how many rays per texel, and how many
//! seconds, brute force needs to reach the error a baked setting reaches, both measured against
//! the same high-ray reference.
//!
//! The peer sums the same bounces as the reference it is fitted against (`bench --bounces`,
//! all bounces by default; the one-bounce rows get a one-bounce peer): the fit below knows
//! nothing of bounces, the ladder it is given does. So the bench can say how many times
//! cheaper relighting by the operators is than path tracing to the same all-bounce error.
//! All-bounce paths are longer, so both the seconds per ray and the noise (the scale `a`)
//! grow with the bounce count.
//!
//! Model, fitted to a measured ladder of ray counts. The reference estimator at `r` rays per
//! texel has error `a · r^-α`; measured against the high-ray reference (`R` rays, independent
//! seed) the two errors add in quadrature: `e(r)² = a² (r^-2α + R^-2α)`. Monte Carlo gives
//! α = 1/2; our scrambled Sobol' sequence converges faster on smooth integrands, so α is fitted
//! (log-log least squares on the errors with the reference's share removed, iterated to a fixed
//! point, α clamped to [0.25, 2]) rather than assumed. Time is fitted as `t(r) = t₀ + k·r`.
//! Then `r(e) = ((e² − a² R^-2α) / a²)^(-1/2α)`, and an error at or below the reference's own
//! noise `a · R^-α` cannot be resolved: [`BruteForceFit::rays_for_error`] returns None there.

/// One brute-force run: rays per texel, relative L2 error against the reference, seconds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BruteForceRun {
    pub rays: u32,
    pub error: f64,
    pub seconds: f64,
}

/// The fitted error and time models of brute force on one scene and texel layout.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BruteForceFit {
    /// a in `e(r) = a · r^-α`.
    pub scale: f64,
    /// α (1/2 for plain Monte Carlo).
    pub exponent: f64,
    /// R: rays per texel of the high-ray reference.
    pub reference_rays: u32,
    /// `t(r) = t₀ + k·r`: seconds independent of the ray count (direct light, setup).
    pub seconds_fixed: f64,
    /// k: seconds per ray per texel (whole scene).
    pub seconds_per_ray: f64,
}

const EXPONENT_RANGE: (f64, f64) = (0.25, 2.0);

impl BruteForceFit {
    /// Fits the models to runs at two or more distinct ray counts (None otherwise).
    pub fn fit(runs: &[BruteForceRun], reference_rays: u32) -> Option<BruteForceFit> {
        let runs: Vec<&BruteForceRun> = runs
            .iter()
            .filter(|r| r.rays > 0 && r.error > 0.0 && r.error.is_finite())
            .collect();
        let lowest = runs.iter().map(|r| r.rays).min()?;
        if runs.iter().all(|r| r.rays == lowest) {
            return None;
        }
        let reference = reference_rays as f64;
        let log_rays: Vec<f64> = runs.iter().map(|r| (r.rays as f64).ln()).collect();
        let mean_log_rays = log_rays.iter().sum::<f64>() / log_rays.len() as f64;
        let var_log_rays: f64 = log_rays.iter().map(|x| (x - mean_log_rays).powi(2)).sum();
        let (mut scale, mut exponent) = (0.0, 0.5);
        for _ in 0..100 {
            // Remove the reference's share at the current estimate, then refit the power law.
            let noise2 = scale * scale * reference.powf(-2.0 * exponent);
            let log_errors: Vec<f64> = runs
                .iter()
                .map(|r| {
                    (r.error * r.error - noise2)
                        .max(1e-6 * r.error * r.error)
                        .sqrt()
                        .ln()
                })
                .collect();
            let mean_log_error = log_errors.iter().sum::<f64>() / log_errors.len() as f64;
            let cov: f64 = log_rays
                .iter()
                .zip(&log_errors)
                .map(|(x, y)| (x - mean_log_rays) * (y - mean_log_error))
                .sum();
            let next_exponent = (-cov / var_log_rays).clamp(EXPONENT_RANGE.0, EXPONENT_RANGE.1);
            let next_scale = (mean_log_error + next_exponent * mean_log_rays).exp();
            let converged = (next_exponent - exponent).abs() < 1e-12
                && (next_scale - scale).abs() <= 1e-12 * next_scale;
            (scale, exponent) = (next_scale, next_exponent);
            if converged {
                break;
            }
        }
        // Ordinary least squares for t = t0 + k r.
        let n = runs.len() as f64;
        let mean_r = runs.iter().map(|r| r.rays as f64).sum::<f64>() / n;
        let mean_t = runs.iter().map(|r| r.seconds).sum::<f64>() / n;
        let cov: f64 = runs
            .iter()
            .map(|r| (r.rays as f64 - mean_r) * (r.seconds - mean_t))
            .sum();
        let var: f64 = runs.iter().map(|r| (r.rays as f64 - mean_r).powi(2)).sum();
        let seconds_per_ray = (cov / var).max(0.0);
        let seconds_fixed = (mean_t - seconds_per_ray * mean_r).max(0.0);
        Some(BruteForceFit {
            scale,
            exponent,
            reference_rays,
            seconds_fixed,
            seconds_per_ray,
        })
    }

    /// The model's error against the reference at `rays` rays per texel.
    pub fn error_at(&self, rays: f64) -> f64 {
        let reference = self.reference_rays as f64;
        self.scale * (rays.powf(-2.0 * self.exponent) + reference.powf(-2.0 * self.exponent)).sqrt()
    }

    /// Rays per texel brute force needs to reach `error` (None: below the reference's noise).
    pub fn rays_for_error(&self, error: f64) -> Option<f64> {
        let own2 = error * error - self.noise_floor().powi(2);
        (own2 > 0.0 && own2.is_finite())
            .then(|| (own2 / (self.scale * self.scale)).powf(-0.5 / self.exponent))
    }

    /// Seconds brute force needs at `rays` rays per texel.
    pub fn seconds_for_rays(&self, rays: f64) -> f64 {
        self.seconds_fixed + self.seconds_per_ray * rays
    }

    /// The error floor set by the high-ray reference's own noise.
    pub fn noise_floor(&self) -> f64 {
        self.scale * (self.reference_rays as f64).powf(-self.exponent)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model(scale: f64, exponent: f64, reference: u32) -> BruteForceFit {
        BruteForceFit {
            scale,
            exponent,
            reference_rays: reference,
            seconds_fixed: 0.5,
            seconds_per_ray: 0.01,
        }
    }

    fn run(m: &BruteForceFit, rays: u32) -> BruteForceRun {
        BruteForceRun {
            rays,
            error: m.error_at(rays as f64),
            seconds: m.seconds_for_rays(rays as f64),
        }
    }

    fn check_recovers(scale: f64, exponent: f64, ladder: &[u32]) {
        let truth = model(scale, exponent, 4096);
        let runs: Vec<BruteForceRun> = ladder.iter().map(|&r| run(&truth, r)).collect();
        let fit = BruteForceFit::fit(&runs, 4096).unwrap();
        assert!((fit.exponent - exponent).abs() < 1e-6, "{fit:?}");
        assert!((fit.scale / scale - 1.0).abs() < 1e-6, "{fit:?}");
        assert!((fit.seconds_fixed - 0.5).abs() < 1e-9);
        assert!((fit.seconds_per_ray - 0.01).abs() < 1e-12);
        // The error brute force has at 256 rays needs 256 rays.
        let e256 = truth.error_at(256.0);
        assert!((fit.rays_for_error(e256).unwrap() / 256.0 - 1.0).abs() < 1e-6);
    }

    #[test]
    fn monte_carlo_and_faster_quasi_monte_carlo_are_recovered() {
        check_recovers(0.3, 0.5, &[16, 64]);
        check_recovers(2.0, 1.2, &[16, 64, 256]);
        check_recovers(0.05, 0.75, &[32, 128]);
    }

    #[test]
    fn hand_computed_numbers() {
        // a = 0.3, α = 1/2, R = 4096: e(16)² = 0.09 (1/16 + 1/4096).
        let m = model(0.3, 0.5, 4096);
        assert!((m.error_at(16.0) - (0.09f64 * (0.0625 + 1.0 / 4096.0)).sqrt()).abs() < 1e-15);
        // Noise floor 0.3 / 64 = 0.0046875; nothing at or below it is reachable.
        assert!((m.noise_floor() - 0.0046875).abs() < 1e-15);
        assert_eq!(m.rays_for_error(0.004), None);
        // e = 0.03: own error² = 0.0009 − 0.0046875² → r = 0.09 / that = 103.1...
        let own2 = 0.0009 - 0.0046875f64.powi(2);
        assert!((m.rays_for_error(0.03).unwrap() - 0.09 / own2).abs() < 1e-9);
        assert!((m.seconds_for_rays(256.0) - 3.06).abs() < 1e-12);
    }

    #[test]
    fn exponent_is_clamped_and_too_few_runs_give_none() {
        let flat = [
            BruteForceRun {
                rays: 16,
                error: 0.1,
                seconds: 1.0,
            },
            BruteForceRun {
                rays: 64,
                error: 0.1,
                seconds: 2.0,
            },
        ];
        let fit = BruteForceFit::fit(&flat, 4096).unwrap();
        assert_eq!(fit.exponent, 0.25);
        assert_eq!(BruteForceFit::fit(&flat[..1], 4096), None);
        assert_eq!(BruteForceFit::fit(&[flat[0], flat[0]], 4096), None);
        assert_eq!(BruteForceFit::fit(&[], 4096), None);
    }
}
