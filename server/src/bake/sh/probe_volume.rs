//! U_dyn (paper 000 §5): a regular grid of SH radiance probes covering the blocks, mapping the
//! blocks' `b` and the clutter's `c` to incident radiance, for dynamic objects (DNRT reads it)
//! and for MRT-style shading of clutter.
//!
//! Probe `p` at `x_p` holds `L_lm = (4π/N) Σ_rays L(hit) Y_lm(ω)` over N uniform sphere directions
//! (`crate`'s SH convention in `lightfarm_proto::sh`), where `L(hit)` is `L_imp^A b_A` on a block
//! texel or `B_j c_j` on a clutter texel: the radiance of direct-lit surfaces, so a receiver
//! shaded from the probe gets one-bounce light. Grid points outside every block or inside a
//! clutter box get no probe. Units: metres; radiance per unit of the coefficients.
//!
//! Invariant: rows are `probe · 9 + coefficient`, ascending per entry; deterministic per probe.

use std::collections::BTreeMap;

use faer::Mat;
use rayon::prelude::*;

use lightfarm_proto::scene::Scene;
use lightfarm_proto::sh::{sh_basis, SH_COEFFS};

use crate::bake::drt::build::{ClutterProjection, DeltaBlock};
use crate::bake::drt::lit_source::LitSource;
use crate::bake::math::sampling::{sobol_2d, stream_key, Purpose};
use crate::bake::mrt::shape::ShapeOperators;
use crate::bake::scene::geometry::Geometry;
use crate::bake::sh::gather::{implicit_source_hit, sh_rows};
use crate::bake::tracer::Tracer;

/// The grid and its operators.
pub struct ProbeVolumeOps {
    pub origin: [f64; 3],
    pub spacing: f64,
    pub dims: [usize; 3],
    pub slot: Vec<u32>,
    pub n_probes: usize,
    pub entries: Vec<DeltaBlock>,
}

/// Uniform direction on the sphere from two uniform numbers.
pub fn sample_uniform_sphere(u: [f64; 2]) -> [f64; 3] {
    let z = 1.0 - 2.0 * u[0];
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * std::f64::consts::PI * u[1];
    [r * phi.cos(), r * phi.sin(), z]
}

/// Builds the probe volume. `clutter` lists the clutter bases (their index is the
/// `DeltaSource::Clutter` index); `projection_of[c]` maps a scene clutter index to it.
pub fn build_probe_volume(
    scene: &Scene,
    g: &Geometry,
    shapes: &[&ShapeOperators],
    clutter: &[ClutterProjection],
    projection_of: &[Option<usize>],
    progress: &(dyn Fn(u64) + Sync),
) -> ProbeVolumeOps {
    let spacing = scene.settings.probe_spacing;
    let bounds = scene.bounds();
    let dims: [usize; 3] =
        [0, 1, 2].map(|k| ((bounds.max[k] - bounds.min[k]) / spacing).ceil().max(1.0) as usize);
    let origin: [f64; 3] = [0, 1, 2].map(|k| {
        let used = dims[k] as f64 * spacing;
        bounds.min[k] + 0.5 * (bounds.max[k] - bounds.min[k] - used) + 0.5 * spacing
    });
    let inside_block = |p: [f64; 3]| {
        scene
            .blocks
            .iter()
            .any(|b| (0..3).all(|k| p[k] > b.min[k] && p[k] < b.max[k]))
    };
    let inside_clutter = |p: [f64; 3]| {
        scene
            .clutter
            .iter()
            .filter_map(|c| c.box_)
            .any(|b| (0..3).all(|k| p[k] >= b.min[k] && p[k] <= b.max[k]))
    };
    let mut slot = vec![u32::MAX; dims[0] * dims[1] * dims[2]];
    let mut positions = Vec::new();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let p = [
                    origin[0] + i as f64 * spacing,
                    origin[1] + j as f64 * spacing,
                    origin[2] + k as f64 * spacing,
                ];
                if inside_block(p) && !inside_clutter(p) {
                    slot[(k * dims[1] + j) * dims[0] + i] = positions.len() as u32;
                    positions.push(p);
                }
            }
        }
    }
    let tracer = Tracer::new(g.primitives.clone(), g.scale());
    let rays = scene.settings.rays_per_texel;
    let weight = 4.0 * std::f64::consts::PI / rays as f64;
    // Per probe: (source, hit texel local index, sh basis of the ray) in ray order.
    let hits: Vec<Vec<(LitSource, usize, [f64; SH_COEFFS])>> = positions
        .par_iter()
        .enumerate()
        .map(|(p, x)| {
            let key = stream_key(scene.settings.seed, Purpose::Probes, p as u64);
            let mut out = Vec::new();
            for i in 0..rays {
                let d = sample_uniform_sphere(sobol_2d(key, i));
                if let Some((source, local)) = implicit_source_hit(g, &tracer, projection_of, *x, d)
                {
                    out.push((source, local, sh_basis(d)));
                }
            }
            progress(1);
            out
        })
        .collect();
    let mut per_source: BTreeMap<LitSource, BTreeMap<u32, Vec<f64>>> = BTreeMap::new();
    for (p, list) in hits.iter().enumerate() {
        // Sum the SH basis of rays landing on the same texel first.
        let mut by_texel: BTreeMap<(LitSource, usize), [f64; SH_COEFFS]> = BTreeMap::new();
        for (key, local, y) in list {
            let acc = by_texel.entry((*key, *local)).or_insert([0.0; SH_COEFFS]);
            for (a, v) in acc.iter_mut().zip(y) {
                *a += weight * v;
            }
        }
        for (key, rows) in sh_rows(&by_texel, shapes, clutter) {
            let target = per_source.entry(key).or_default();
            for (lm, row) in rows.into_iter().enumerate() {
                target.insert((p * SH_COEFFS + lm) as u32, row);
            }
        }
    }
    let entries = per_source
        .into_iter()
        .map(|(key, rows)| {
            let values: Vec<&Vec<f64>> = rows.values().collect();
            let width = values.first().map_or(0, |v| v.len());
            DeltaBlock {
                rows: rows.keys().copied().collect(),
                source: key.into(),
                matrix: Mat::from_fn(values.len(), width, |i, j| values[i][j]),
            }
        })
        .collect();
    ProbeVolumeOps {
        origin,
        spacing,
        dims,
        slot,
        n_probes: positions.len(),
        entries,
    }
}
