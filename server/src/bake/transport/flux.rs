//! Compact transport turned so that one row of each stored factor carries the flux it delivers
//! (ours, as [`crate::bake::mrt::flux`] does for the shapes): the bundle's 8-bit transport then
//! keeps a closed level's energy from bounce to bounce.
//!
//! Transport into block B is `Y_B · Z'_B · [Q_A b_A]_A` (`Y_B` texels × k, `Z'_B` k × Σ j_A,
//! `Q_A` a source's shared basis, or the identity on A's r coefficients without one). The flux
//! it delivers is `a_Bᵀ Y_B Z'_B [Q_A b_A]` (`a_B`: B's texel areas). The bundle rounds `Z'`
//! and `Q` to 8 bits; a fixed matrix's rounding moves the flux of every bounce the same way, so
//! all bounces multiply it by about `1/(1 − ρ)`. A closed 28-block shaft (ρ = 0.8, T = 8,
//! tolerance 1e-4) kept +0.47% of one bounce's flux and +2.64% over the geometric series at all
//! bounces stored in 8 bits, against +0.19% and +0.70% with the transport stored losslessly.
//!
//! Two turns (each an orthogonal [`Turn`], so every product is unchanged in exact arithmetic):
//! 1. each receiver's k-space, so that `a_Bᵀ Y_B = ‖w_B‖ e₀ᵀ`: only row 0 of `Z'_B` carries
//!    B's flux, and rounding the other rows cannot move it;
//! 2. each shared basis's j-space, so that `u_A = Σ_B a_Bᵀ Y_B Z'_BA` (the flux A's basis
//!    coefficients deliver to all its receivers) is along `e₀`: only row 0 of `Q_A` carries it.
//!
//! Units: areas in square metres; a turn depends on directions only, so scaling every area
//! changes nothing. Invariant: entries are turned in parallel but each one's arithmetic is
//! sequential and the bases' flux is summed in entry order, so the bits do not depend on the
//! thread count; a pure function of the factored f32 transport and the areas.

use faer::Mat;
use rayon::prelude::*;

use lightfarm_proto::bundle::SourceBases;

use crate::bake::math::matrix::{from_matrix, to_matrix};
use crate::bake::mrt::flux::{flux_weights, Turn};

/// Turns `transport` (module doc) under `area[b]`, block b's texel areas in its texel order;
/// `rank[b]`: block b's shape rank (the width of its columns in a `Z'` without a basis).
pub fn flux_first_transport(transport: &mut SourceBases, area: &[Vec<f64>], rank: &[usize]) {
    // 1. Each receiver's k-space; keeps the turned factors in f64 for step 2.
    let mut turned: Vec<(Mat<f64>, Mat<f64>)> = transport
        .entries
        .par_iter()
        .map(|e| {
            let (mut y, mut z) = (from_matrix(&e.y), from_matrix(&e.z));
            let a = &area[e.target_block as usize];
            assert_eq!(y.nrows(), a.len(), "block {}: texel areas", e.target_block);
            let w = flux_weights(&y, a);
            if let Some(turn) = Turn::onto_first(&w) {
                for x in 0..y.nrows() {
                    turn.row(&mut y, x, 0);
                }
                for c in 0..z.ncols() {
                    turn.column(&mut z, c);
                }
            }
            (y, z)
        })
        .collect();
    // Where each source's columns start in each entry's `Z'`, and the sources with a basis.
    let mut basis_of = vec![None; rank.len()];
    for (i, b) in transport.bases.iter().enumerate() {
        basis_of[b.source_block as usize] = Some(i);
    }
    let width = |s: u32| match basis_of[s as usize] {
        Some(i) => transport.bases[i].q.rows as usize,
        None => rank[s as usize],
    };
    // 2. Each basis's j-space: u_A summed over its receivers in entry order.
    let mut u: Vec<Vec<f64>> = transport
        .bases
        .iter()
        .map(|b| vec![0.0; b.q.rows as usize])
        .collect();
    for (e, (y, z)) in transport.entries.iter().zip(&turned) {
        let a = &area[e.target_block as usize];
        let flux_y = flux_weights(y, a);
        let mut at = 0;
        for &s in &e.sources {
            if let Some(i) = basis_of[s as usize] {
                for (m, um) in u[i].iter_mut().enumerate() {
                    *um += (0..z.nrows())
                        .map(|k| flux_y[k] * z[(k, at + m)])
                        .sum::<f64>();
                }
            }
            at += width(s);
        }
    }
    let turns: Vec<Option<Turn>> = u.iter().map(|u| Turn::onto_first(u)).collect();
    turned
        .par_iter_mut()
        .zip(&transport.entries)
        .for_each(|((_, z), e)| {
            let mut at = 0;
            for &s in &e.sources {
                if let Some(turn) = basis_of[s as usize].and_then(|i| turns[i].as_ref()) {
                    for k in 0..z.nrows() {
                        turn.row(z, k, at);
                    }
                }
                at += width(s);
            }
        });
    transport
        .bases
        .par_iter_mut()
        .zip(&turns)
        .for_each(|(b, turn)| {
            if let Some(turn) = turn {
                let mut q = from_matrix(&b.q);
                for c in 0..q.ncols() {
                    turn.column(&mut q, c);
                }
                b.q = to_matrix(&q);
            }
        });
    for (e, (y, z)) in transport.entries.iter_mut().zip(turned) {
        e.y = to_matrix(&y);
        e.z = to_matrix(&z);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::bundle::{CompactEntry, SourceBasis};
    use lightfarm_proto::testing::Lcg;

    fn random(rng: &mut Lcg, rows: usize, cols: usize, shift: f32) -> Mat<f64> {
        Mat::from_fn(rows, cols, |_, _| f64::from(rng.unit() - shift))
    }

    /// Three blocks (shape ranks 3, 4, 5; 12, 16, 20 texels): receivers 0 and 1 read sources
    /// 1 and 2, source 2 through a basis of rank 2 and source 1 without one; receiver 2
    /// reads source 0. Light that mostly adds up (positive-leaning values), as transport's.
    fn level() -> (SourceBases, Vec<Vec<f64>>, Vec<usize>) {
        let mut rng = Lcg(11);
        let rank = vec![3, 4, 5];
        let texels = [12, 16, 20];
        let q = random(&mut rng, 2, 5, 0.5);
        let mut entry = |target: usize, sources: Vec<u32>, width: usize| CompactEntry {
            target_block: target as u32,
            sources,
            y: to_matrix(&random(&mut rng, texels[target], 3, 0.3)),
            z: to_matrix(&random(&mut rng, 3, width, 0.3)),
        };
        let entries = vec![
            entry(0, vec![1, 2], 4 + 2),
            entry(1, vec![1, 2], 4 + 2),
            entry(2, vec![0], 3),
        ];
        let area = texels
            .iter()
            .map(|&n| (0..n).map(|x| 0.5 + (x % 3) as f64 * 0.25).collect())
            .collect();
        let bases = vec![SourceBasis {
            source_block: 2,
            q: to_matrix(&q),
        }];
        (SourceBases { bases, entries }, area, rank)
    }

    /// Per entry and source, the operator it applies to the source's shape coefficients:
    /// `Y Z'_A Q_A` (texels × r_A).
    fn operators(t: &SourceBases, rank: &[usize]) -> Vec<Mat<f64>> {
        let mut out = Vec::new();
        for e in &t.entries {
            let (y, z) = (from_matrix(&e.y), from_matrix(&e.z));
            let mut at = 0;
            for &s in &e.sources {
                let basis = t.bases.iter().find(|b| b.source_block == s);
                let width = basis.map_or(rank[s as usize], |b| b.q.rows as usize);
                let part = &y * z.subcols(at, width);
                out.push(match basis {
                    Some(b) => part * from_matrix(&b.q),
                    None => part,
                });
                at += width;
            }
        }
        out
    }

    /// The flux all receivers get from coefficients `b` (per block), with each factor
    /// optionally perturbed: `Z'` rows from `z_from` on, `Q` rows from `q_from` on, by 5% of
    /// the matrix's largest value, pseudo-randomly (an 8-bit-like rounding).
    fn flux(
        t: &SourceBases,
        area: &[Vec<f64>],
        b: &[Vec<f64>],
        z_from: usize,
        q_from: usize,
    ) -> f64 {
        let mut rng = Lcg(99);
        let mut perturbed = |m: &Mat<f64>, from: usize| {
            let big = (0..m.nrows())
                .flat_map(|i| (0..m.ncols()).map(move |j| (i, j)))
                .map(|(i, j)| m[(i, j)].abs())
                .fold(0.0, f64::max);
            Mat::from_fn(m.nrows(), m.ncols(), |i, j| {
                let noise = f64::from(rng.unit()) - 0.5;
                m[(i, j)] + if i >= from { 0.1 * big * noise } else { 0.0 }
            })
        };
        let bases: Vec<(u32, Mat<f64>)> = t
            .bases
            .iter()
            .map(|bs| (bs.source_block, perturbed(&from_matrix(&bs.q), q_from)))
            .collect();
        let mut total = 0.0;
        for e in &t.entries {
            let (y, z) = (from_matrix(&e.y), perturbed(&from_matrix(&e.z), z_from));
            let mut v = Vec::new();
            for &s in &e.sources {
                match bases.iter().find(|(k, _)| *k == s) {
                    Some((_, q)) => v.extend((0..q.nrows()).map(|m| {
                        (0..q.ncols())
                            .map(|c| q[(m, c)] * b[s as usize][c])
                            .sum::<f64>()
                    })),
                    None => v.extend(&b[s as usize]),
                }
            }
            let a = &area[e.target_block as usize];
            for x in 0..y.nrows() {
                let light: f64 = (0..z.nrows())
                    .map(|k| y[(x, k)] * (0..z.ncols()).map(|c| z[(k, c)] * v[c]).sum::<f64>())
                    .sum();
                total += a[x] * light;
            }
        }
        total
    }

    #[test]
    fn turned_transport_applies_the_same_operators_with_the_flux_in_row_zero() {
        let (mut t, area, rank) = level();
        let before = operators(&t, &rank);
        flux_first_transport(&mut t, &area, &rank);
        for (a, b) in before.iter().zip(operators(&t, &rank)) {
            for i in 0..a.nrows() {
                for j in 0..a.ncols() {
                    assert!((a[(i, j)] - b[(i, j)]).abs() < 1e-5, "{i} {j}");
                }
            }
        }
        // Each receiver's flux weights aᵀ Y along +e₀ (to f32 rounding).
        for e in &t.entries {
            let y = from_matrix(&e.y);
            let a = &area[e.target_block as usize];
            let w: Vec<f64> = (0..y.ncols())
                .map(|i| (0..y.nrows()).map(|x| a[x] * y[(x, i)]).sum())
                .collect();
            assert!(w[0] > 0.0);
            for wi in &w[1..] {
                assert!(wi.abs() < 1e-5 * w[0], "{w:?}");
            }
        }
    }

    #[test]
    fn rounding_every_row_but_the_first_keeps_the_flux() {
        let (mut t, area, rank) = level();
        let mut rng = Lcg(5);
        let b: Vec<Vec<f64>> = rank
            .iter()
            .map(|&r| (0..r).map(|_| f64::from(rng.unit())).collect())
            .collect();
        let exact = flux(&t, &area, &b, usize::MAX, usize::MAX);
        let unturned = flux(&t, &area, &b, 0, 0);
        flux_first_transport(&mut t, &area, &rank);
        let turned_exact = flux(&t, &area, &b, usize::MAX, usize::MAX);
        let turned = flux(&t, &area, &b, 1, 1);
        assert!((turned_exact - exact).abs() < 1e-5 * exact.abs());
        assert!(
            (unturned - exact).abs() > 1e-3 * exact.abs(),
            "{unturned} {exact}"
        );
        assert!(
            (turned - exact).abs() < 1e-5 * exact.abs(),
            "{turned} {exact}"
        );
    }

    #[test]
    fn scaling_every_area_turns_alike() {
        let (mut small, area, rank) = level();
        let mut big = small.clone();
        let scaled: Vec<Vec<f64>> = area
            .iter()
            .map(|a| a.iter().map(|x| x * 1e6).collect())
            .collect();
        flux_first_transport(&mut small, &area, &rank);
        flux_first_transport(&mut big, &scaled, &rank);
        for (a, b) in small.entries.iter().zip(&big.entries) {
            for (x, y) in
                a.y.data
                    .iter()
                    .chain(&a.z.data)
                    .zip(b.y.data.iter().chain(&b.z.data))
            {
                assert!((x - y).abs() <= 1e-5 * x.abs().max(1.0), "{x} {y}");
            }
        }
        for (a, b) in small.bases.iter().zip(&big.bases) {
            for (x, y) in a.q.data.iter().zip(&b.q.data) {
                assert!((x - y).abs() <= 1e-5 * x.abs().max(1.0), "{x} {y}");
            }
        }
    }
}
