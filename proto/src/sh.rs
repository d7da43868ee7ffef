//! Spherical-harmonics convention shared by server and client: real SH up to order 2
//! (bands l = 0, 1, 2; 9 coefficients), world frame (x, y, z), y up.
//!
//! Coefficient order and basis (Sloan, "Stupid SH tricks"):
//! `0: Y00 = 0.282095`, `1: Y1-1 = 0.488603 y`, `2: Y10 = 0.488603 z`, `3: Y11 = 0.488603 x`,
//! `4: Y2-2 = 1.092548 xy`, `5: Y2-1 = 1.092548 yz`, `6: Y20 = 0.315392 (3z² − 1)`,
//! `7: Y21 = 1.092548 xz`, `8: Y22 = 0.546274 (x² − y²)`. The first 4 coefficients are the
//! order-1 (4-coefficient) truncation.
//!
//! Radiance is projected as `L_lm = ∫ L(ω) Y_lm(ω) dω`; irradiance at normal n is
//! `E(n) = Σ Â_l L_lm Y_lm(n)` with `Â_0 = π`, `Â_1 = 2π/3`, `Â_2 = π/4` (Ramamoorthi–Hanrahan).

use std::f64::consts::PI;

/// Coefficients per channel at order 2.
pub const SH_COEFFS: usize = 9;

/// The 9 basis functions at unit direction `d`.
pub fn sh_basis(d: [f64; 3]) -> [f64; SH_COEFFS] {
    let [x, y, z] = d;
    [
        0.282_094_791_773_878_1,
        0.488_602_511_902_919_9 * y,
        0.488_602_511_902_919_9 * z,
        0.488_602_511_902_919_9 * x,
        1.092_548_430_592_079_2 * x * y,
        1.092_548_430_592_079_2 * y * z,
        0.315_391_565_252_520_05 * (3.0 * z * z - 1.0),
        1.092_548_430_592_079_2 * x * z,
        0.546_274_215_296_039_6 * (x * x - y * y),
    ]
}

/// Cosine-lobe convolution weights per coefficient (`Â_l`).
pub fn irradiance_weights() -> [f64; SH_COEFFS] {
    let (a0, a1, a2) = (PI, 2.0 * PI / 3.0, PI / 4.0);
    [a0, a1, a1, a1, a2, a2, a2, a2, a2]
}

/// Irradiance at normal `n` from radiance coefficients `l` (one channel).
pub fn irradiance(l: &[f64; SH_COEFFS], n: [f64; 3]) -> f64 {
    let y = sh_basis(n);
    let a = irradiance_weights();
    (0..SH_COEFFS).map(|k| a[k] * l[k] * y[k]).sum()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Deterministic, nearly uniform directions (also used by `sh_rotation`'s tests).
    pub(crate) fn sphere_points(n: usize) -> Vec<[f64; 3]> {
        // Fibonacci sphere: nearly uniform, deterministic.
        let golden = PI * (3.0 - 5f64.sqrt());
        (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let phi = golden * i as f64;
                [r * phi.cos(), r * phi.sin(), z]
            })
            .collect()
    }

    #[test]
    fn basis_is_orthonormal() {
        let pts = sphere_points(20000);
        let w = 4.0 * PI / pts.len() as f64;
        for a in 0..SH_COEFFS {
            for b in 0..SH_COEFFS {
                let dot: f64 = pts
                    .iter()
                    .map(|d| sh_basis(*d)[a] * sh_basis(*d)[b] * w)
                    .sum();
                let expected = if a == b { 1.0 } else { 0.0 };
                assert!((dot - expected).abs() < 2e-3, "<Y{a}, Y{b}> = {dot}");
            }
        }
    }

    #[test]
    fn project_then_reconstruct_is_exact_for_band_limited_input() {
        // L(ω) = 1 + 0.5 y + 0.3 xz is in the span of bands 0..2.
        let f = |d: [f64; 3]| 1.0 + 0.5 * d[1] + 0.3 * d[0] * d[2];
        let pts = sphere_points(40000);
        let w = 4.0 * PI / pts.len() as f64;
        let mut l = [0.0; SH_COEFFS];
        for d in &pts {
            let y = sh_basis(*d);
            for k in 0..SH_COEFFS {
                l[k] += f(*d) * y[k] * w;
            }
        }
        for d in sphere_points(50) {
            let back: f64 = (0..SH_COEFFS).map(|k| l[k] * sh_basis(d)[k]).sum();
            assert!((back - f(d)).abs() < 2e-3, "{back} vs {}", f(d));
        }
    }

    #[test]
    fn constant_radiance_gives_pi_irradiance() {
        // L = 1 everywhere: L_00 = √(4π), E = π for any normal.
        let mut l = [0.0; SH_COEFFS];
        l[0] = (4.0 * PI).sqrt();
        for n in sphere_points(10) {
            assert!((irradiance(&l, n) - PI).abs() < 1e-9);
        }
    }
}
