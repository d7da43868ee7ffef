//! A shape's coefficients turned so that the first alone carries the flux (ours, past the MRT
//! paper): the bundle's 8-bit `T_d→b` then keeps a closed level's energy.
//!
//! MRT reads direct light `d` (texel radiance) through `b = T_d→b d` and rebuilds the light
//! leaving the texels as `L_imp b`; every bounce inside the block (`U_b = F L_imp`) and every
//! traced transport out of it (`S L_imp`) starts from that rebuilt light. In a closed level every
//! ray lands somewhere, so the flux one bounce delivers is the rebuilt light's flux
//! `aᵀ L_imp b = wᵀ b` (`a`: texel areas, `w = L_impᵀ a`: each coefficient's flux).
//!
//! The bundle stores `T_d→b` in 8 bits a row at a time (one range per coefficient). `T_d→b` is
//! an oblique projection (`V_rᵀ S⁻¹ Pᵀ`): its rows are large and cancel in `L_imp T_d→b`, and
//! rounding row j moves the flux by `w_j` times its error. Shared by every block of the shape,
//! those errors do not average out: a closed level of 44 blocks (a 30 m hall under a 12 m
//! shaft, with a closet; ρ = 0.8, T = 8, 1,024 rays, tolerance 1e-4) gained 2.75% of one
//! bounce's flux and 12.7% over the geometric series at all bounces, which multiply it by
//! about `1/(1 − ρ)`; stored losslessly, +0.03% and +0.24%.
//!
//! [`flux_first`] turns the coefficient space by an orthogonal `R` (a Householder reflection,
//! one sign fixed) with `R w = ‖w‖ e₀`: `L_imp ← L_imp Rᵀ`, `T_d→b ← R T_d→b`. `L_imp T_d→b` is
//! unchanged, and so is everything built on it in exact arithmetic; but now only row 0 of
//! `T_d→b` (`ŵᵀ T_d→b`) moves the flux, and rounding the others cannot. Same level, 8-bit:
//! −0.09% and −0.16%, at the same bytes (`tests/quantised_flux.rs`: a 28-block shaft, +5.5%
//! at one bounce before, +0.5% after).
//!
//! Units: `a` in the shape's square metres; `R` depends on `w`'s direction only, so scaling
//! every area changes nothing and the bake stays free of absolute lengths.

use faer::Mat;

/// Turns the coefficients of `t_db` (r × texels) and `l_imp` (texels × r) so that, under texel
/// areas `area`, `areaᵀ l_imp` is `‖w‖ e₀` (coefficient 0 carries all the flux) while
/// `l_imp t_db` stays the same to rounding. Implicit lights carrying no flux at all (`w = 0`)
/// are left as they are.
pub fn flux_first(t_db: &mut Mat<f64>, l_imp: &mut Mat<f64>, area: &[f64]) {
    let (r, n) = (t_db.nrows(), t_db.ncols());
    assert_eq!((l_imp.nrows(), l_imp.ncols(), area.len()), (n, r, n));
    let w = flux_weights(l_imp, area);
    if let Some(turn) = Turn::onto_first(&w) {
        for x in 0..n {
            turn.column(t_db, x);
            turn.row(l_imp, x, 0);
        }
    }
}

/// Each column's flux under texel areas `area`: `mᵀ area` (`m` texels × columns), every
/// column's terms summed in texel order.
pub fn flux_weights(m: &Mat<f64>, area: &[f64]) -> Vec<f64> {
    (0..m.ncols())
        .map(|j| (0..m.nrows()).map(|x| m[(x, j)] * area[x]).sum())
        .collect()
}

/// The orthogonal turn `D H` of a coefficient space that maps the direction of a flux vector
/// `w` onto `+e₀` (`H = I − 2 v vᵀ / vᵀv` with `v = ŵ + s e₀`, `s` the sign of `ŵ₀` so nothing
/// cancels, and `D` negating coefficient 0 when `s = 1`). A factorisation `L · M` with the
/// space between them is turned as `L ← L H D`, `M ← D H M` ([`Turn::row`], [`Turn::column`]):
/// the product is unchanged, and `wᵀ M ← ‖w‖ e₀ᵀ (D H M)`, so only `M`'s first row carries
/// what `w` weighs.
pub struct Turn {
    v: Vec<f64>,
    scale: f64,
    s: f64,
}

impl Turn {
    /// The turn of `w`, or None when `w` is zero or not finite (nothing to turn).
    pub fn onto_first(w: &[f64]) -> Option<Turn> {
        let norm = w.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !(norm.is_finite() && norm > 0.0) {
            return None;
        }
        // v = ŵ + s e₀; H = I − 2 v vᵀ / vᵀv maps ŵ to −s e₀, and coefficient 0 is then
        // negated when s = 1, so that ŵ goes to +e₀. H = Hᵀ = H⁻¹.
        let s = if w[0] >= 0.0 { 1.0 } else { -1.0 };
        let mut v: Vec<f64> = w.iter().map(|x| x / norm).collect();
        v[0] += s;
        let scale = 2.0 / v.iter().map(|x| x * x).sum::<f64>();
        Some(Turn { v, scale, s })
    }

    /// Column `x` of `m` (the right factor, coefficients as its rows) turned: `D H m[:, x]`.
    pub fn column(&self, m: &mut Mat<f64>, x: usize) {
        let r = self.v.len();
        let dot = self.scale * (0..r).map(|j| self.v[j] * m[(j, x)]).sum::<f64>();
        for j in 0..r {
            m[(j, x)] -= dot * self.v[j];
        }
        m[(0, x)] *= -self.s;
    }

    /// Row `x` of `m` (the left factor, coefficients as its columns from `first`) turned:
    /// `m[x, first..first + r] H D`.
    pub fn row(&self, m: &mut Mat<f64>, x: usize, first: usize) {
        let r = self.v.len();
        let dot = self.scale * (0..r).map(|j| m[(x, first + j)] * self.v[j]).sum::<f64>();
        for j in 0..r {
            m[(x, first + j)] -= dot * self.v[j];
        }
        m[(x, first)] *= -self.s;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic pseudo-random values in [-1, 1).
    fn values(seed: u64, n: usize) -> Vec<f64> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 11) as f64 / (1u64 << 52) as f64 - 1.0
            })
            .collect()
    }

    /// A shape-like pair: positive implicit lights, a `T` with large cancelling rows.
    fn pair(n: usize, r: usize, seed: u64) -> (Mat<f64>, Mat<f64>) {
        let lv = values(seed, n * r);
        let tv = values(seed + 1, n * r);
        let l = Mat::from_fn(n, r, |x, j| lv[x * r + j] + 0.3);
        let t = Mat::from_fn(r, n, |j, x| 5.0 * tv[j * n + x]);
        (l, t)
    }

    fn flux_weights(l: &Mat<f64>, area: &[f64]) -> Vec<f64> {
        (0..l.ncols())
            .map(|j| (0..l.nrows()).map(|x| l[(x, j)] * area[x]).sum())
            .collect()
    }

    #[test]
    fn turned_coefficients_rebuild_the_same_light_with_the_flux_in_the_first() {
        let (n, r) = (20, 6);
        let (l0, t0) = pair(n, r, 4);
        let area: Vec<f64> = (0..n).map(|x| 1.0 + (x % 4) as f64 * 0.5).collect();
        let w0 = flux_weights(&l0, &area);
        let (mut l, mut t) = (l0.clone(), t0.clone());
        flux_first(&mut t, &mut l, &area);
        // L T unchanged.
        let (before, after) = (&l0 * &t0, &l * &t);
        for x in 0..n {
            for y in 0..n {
                assert!((before[(x, y)] - after[(x, y)]).abs() < 1e-12, "{x} {y}");
            }
        }
        // w is along +e₀ with the same length, and row 0 of T is ŵᵀ T.
        let w = flux_weights(&l, &area);
        let norm = w0.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!((w[0] - norm).abs() < 1e-12 * norm, "{w:?}");
        for wj in &w[1..] {
            assert!(wj.abs() < 1e-12 * norm, "{w:?}");
        }
        for x in 0..n {
            let row0: f64 = (0..r).map(|j| w0[j] / norm * t0[(j, x)]).sum();
            assert!(
                (t[(0, x)] - row0).abs() < 1e-12 * row0.abs().max(1.0),
                "{x}"
            );
        }
    }

    #[test]
    fn rounding_every_row_but_the_first_keeps_the_flux() {
        let (n, r) = (30, 8);
        let (mut l, mut t) = pair(n, r, 9);
        let area: Vec<f64> = (0..n).map(|x| 0.25 + (x % 3) as f64).collect();
        let d: Vec<f64> = values(12, n).iter().map(|v| v + 1.0).collect();
        let flux = |l: &Mat<f64>, t: &Mat<f64>| -> f64 {
            let b: Vec<f64> = (0..r)
                .map(|j| (0..n).map(|x| t[(j, x)] * d[x]).sum())
                .collect();
            (0..n)
                .map(|x| area[x] * (0..r).map(|j| l[(x, j)] * b[j]).sum::<f64>())
                .sum()
        };
        // An 8-bit-like error on every row: 1% of the row's range, pseudo-random.
        let rounded = |t: &Mat<f64>, from: usize| -> Mat<f64> {
            let noise = values(77, r * n);
            let mut out = t.clone();
            for j in from..r {
                let range = (0..n).map(|x| t[(j, x)].abs()).fold(0.0, f64::max);
                for x in 0..n {
                    out[(j, x)] += 0.01 * range * noise[j * n + x];
                }
            }
            out
        };
        let exact = flux(&l, &t);
        let unturned = flux(&l, &rounded(&t, 0));
        flux_first(&mut t, &mut l, &area);
        assert!((flux(&l, &t) - exact).abs() < 1e-10 * exact.abs());
        let turned = flux(&l, &rounded(&t, 1));
        assert!(
            (unturned - exact).abs() > 1e-3 * exact.abs(),
            "{unturned} {exact}"
        );
        assert!(
            (turned - exact).abs() < 1e-10 * exact.abs(),
            "{turned} {exact}"
        );
    }

    #[test]
    fn scaling_every_area_turns_alike() {
        let (n, r) = (12, 4);
        let (l0, t0) = pair(n, r, 21);
        let area: Vec<f64> = (0..n).map(|x| 1.0 + x as f64).collect();
        let big: Vec<f64> = area.iter().map(|a| a * 1e6).collect();
        let (mut la, mut ta) = (l0.clone(), t0.clone());
        let (mut lb, mut tb) = (l0, t0);
        flux_first(&mut ta, &mut la, &area);
        flux_first(&mut tb, &mut lb, &big);
        for j in 0..r {
            for x in 0..n {
                assert!((ta[(j, x)] - tb[(j, x)]).abs() <= 1e-12 * ta[(j, x)].abs().max(1.0));
                assert!((la[(x, j)] - lb[(x, j)]).abs() <= 1e-12 * la[(x, j)].abs().max(1.0));
            }
        }
    }
}
