//! The discrete one-bounce gather over a whole scene: for each receiving texel, the texels its
//! cosine-weighted rays hit (DRT §3.1, `l_ind = ρ ⊙ F l_d`, albedo-free F).
//!
//! Rows come back sparse: `(hit texel, weight)` with weights summing to at most 1 (rays that
//! miss, leave the level or hit unlit geometry carry nothing). Used for the dense Hašan-style
//! `full` operator (the traced inter-block transport traces its own rays, only those leaving a
//! block through its openings, and its tests check it against these rows).
//!
//! Invariant: row `x` depends only on (seed, purpose, x) and the geometry, never on threads.

use rayon::prelude::*;

use crate::bake::math::sampling::{
    sample_cosine_hemisphere, sobol_2d, stream_key, to_world, Purpose,
};
use crate::bake::mrt::shape::hit_texel;
use crate::bake::scene::geometry::Geometry;
use crate::bake::tracer::Tracer;

/// Sparse rows of F for `texels` (global indices). Weights are hit counts / rays.
pub fn gather_rows(
    g: &Geometry,
    tracer: &Tracer,
    texels: &[usize],
    rays: u32,
    seed: u64,
    purpose: Purpose,
    progress: &(dyn Fn(u64) + Sync),
) -> Vec<Vec<(u32, f32)>> {
    let sign = |s: u32| g.surfaces[s as usize].normal_sign;
    texels
        .par_iter()
        .map(|&x| {
            let texel = &g.texels[x];
            let key = stream_key(seed, purpose, x as u64);
            let mut hits: Vec<u32> = Vec::with_capacity(rays as usize);
            for i in 0..rays {
                let d = to_world(sample_cosine_hemisphere(sobol_2d(key, i)), texel.normal);
                if let Some(hit) = tracer.closest(texel.position, d, f64::INFINITY, &sign) {
                    if let Some(t) = hit_texel(g, tracer, &hit) {
                        hits.push(t as u32);
                    }
                }
            }
            hits.sort_unstable();
            let mut row: Vec<(u32, f32)> = Vec::new();
            let inv = 1.0 / rays as f32;
            for t in hits {
                match row.last_mut() {
                    Some((last, w)) if *last == t => *w += inv,
                    _ => row.push((t, inv)),
                }
            }
            progress(1);
            row
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::scene::Aabb;
    use lightfarm_proto::Face;

    fn unit_box(open: &[Face], t: usize) -> Geometry {
        let mut g = Geometry::default();
        let closed: Vec<Face> = Face::ALL
            .into_iter()
            .filter(|f| !open.contains(f))
            .collect();
        g.add_block(
            0,
            "b",
            &Aabb {
                min: [0.0; 3],
                max: [1.0; 3],
            },
            &closed,
            |_| [0.5; 3],
            t,
        );
        g
    }

    #[test]
    fn closed_box_rows_sum_to_one() {
        let g = unit_box(&[], 4);
        let tracer = Tracer::new(g.primitives.clone(), 1.0);
        let all: Vec<usize> = (0..g.texels.len()).collect();
        for row in gather_rows(&g, &tracer, &all, 256, 0, Purpose::FullOperator, &|_| {}) {
            let sum: f32 = row.iter().map(|(_, w)| w).sum();
            assert!((sum - 1.0).abs() < 1e-5, "{sum}");
        }
    }

    /// Form factor between the centre of a unit square's face and the opposite face of a unit
    /// cube: from the closed form for a point to a parallel coaxial square, F = (2/π)[…].
    #[test]
    fn parallel_and_perpendicular_form_factors_match_closed_forms() {
        let g = unit_box(&[], 1);
        let tracer = Tracer::new(g.primitives.clone(), 1.0);
        // Texel 2 is the -y face (floor) with one texel; its centre sees +y (ceiling, texel 3).
        let rows = gather_rows(&g, &tracer, &[2], 65536, 9, Purpose::FullOperator, &|_| {});
        let to_ceiling = rows[0].iter().find(|(t, _)| *t == 3).unwrap().1 as f64;
        // Point-to-parallel-rectangle (a = b = 1/2 half-widths at distance 1), per quadrant:
        // F = 1/(2π) [ A/√(1+A²) atan(B/√(1+A²)) + B/√(1+B²) atan(A/√(1+B²)) ], times 4.
        let (a, b) = (0.5f64, 0.5f64);
        let quadrant = |a: f64, b: f64| {
            1.0 / (2.0 * std::f64::consts::PI)
                * (a / (1.0 + a * a).sqrt() * (b / (1.0 + a * a).sqrt()).atan()
                    + b / (1.0 + b * b).sqrt() * (a / (1.0 + b * b).sqrt()).atan())
        };
        let expected = 4.0 * quadrant(a, b);
        assert!(
            (to_ceiling - expected).abs() < 2e-3,
            "parallel: {to_ceiling} vs {expected}"
        );
        // By symmetry the four side walls share the rest equally.
        let side: f64 = rows[0]
            .iter()
            .filter(|(t, _)| *t != 3)
            .map(|(_, w)| *w as f64)
            .sum::<f64>()
            / 4.0;
        assert!(
            (side - (1.0 - expected) / 4.0).abs() < 2e-3,
            "perpendicular: {side}"
        );
    }

    #[test]
    fn reciprocity_area_weighted() {
        // A_i F_ij = A_j F_ji for equal-area texels of a closed box: F symmetric up to noise.
        let g = unit_box(&[], 3);
        let tracer = Tracer::new(g.primitives.clone(), 1.0);
        let all: Vec<usize> = (0..g.texels.len()).collect();
        let rows = gather_rows(&g, &tracer, &all, 8192, 1, Purpose::FullOperator, &|_| {});
        let n = g.texels.len();
        let mut f = vec![0.0f64; n * n];
        for (i, row) in rows.iter().enumerate() {
            for (j, w) in row {
                f[i * n + *j as usize] = *w as f64;
            }
        }
        let mut worst: f64 = 0.0;
        for i in 0..n {
            for j in 0..n {
                worst = worst.max((f[i * n + j] - f[j * n + i]).abs());
            }
        }
        // Point-sampled rows are not exactly reciprocal; texels here are 1/3 m so centre
        // sampling differs from area averaging by a few percent of the largest entries.
        let largest = f.iter().cloned().fold(0.0, f64::max);
        assert!(
            worst < 0.35 * largest,
            "worst asymmetry {worst} of {largest}"
        );
    }
}
