//! U_dyn (paper 000 §5): a regular grid of SH radiance probes covering the blocks, mapping the
//! blocks' `b` and the clutter's `c` to incident radiance, for dynamic objects (DNRT reads it)
//! and for MRT-style shading of clutter.
//!
//! Probe `p` at `x_p` holds `L_lm = (4π/N) Σ_rays L(hit) Y_lm(ω)` over N uniform sphere directions
//! (`crate`'s SH convention in `lightfarm_proto::sh`), where `L(hit)` is `L_imp^A b_A` on a block
//! texel or `B_j c_j` on a clutter texel: the radiance of direct-lit surfaces, so a receiver
//! shaded from the probe gets one-bounce light. Grid points outside every block or inside a
//! clutter box get no probe. When every dynamic object lists the regions it stays in
//! ([`Scene::probe_regions`]), the grid is laid out over the lattice points in those regions
//! only — the same lattice: the blocks' bounds cut every `probe_spacing` — so the probes follow
//! where moving objects go, not the level's size. With `probe_volume: always` (the MRT
//! baseline shades clutter from the probes, `eval --method mrt`) the lattice points around
//! each clutter object's bounds, grown by one spacing, are laid out too; by default (`auto`)
//! the volume's only readers are the dynamic objects, and a level's clutter adds no probe.
//! Units: metres; radiance per unit of the coefficients.
//!
//! Invariant: rows are `probe · 9 + coefficient`, ascending per entry; deterministic per probe.

use std::collections::BTreeMap;

use faer::Mat;
use rayon::prelude::*;

use lightfarm_proto::scene::{Aabb, ProbeVolumeMode, Scene};
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

/// The index box `[lo, hi)` of the lattice points (`origin + spacing · index`, `full` points
/// per axis) inside any of `regions`; `lo == hi` on some axis when none is.
fn lattice_span(
    regions: &[Aabb],
    origin: [f64; 3],
    spacing: f64,
    full: [usize; 3],
) -> ([usize; 3], [usize; 3]) {
    let (mut lo, mut hi) = (full, [0; 3]);
    for r in regions {
        let first = [0, 1, 2].map(|k| ((r.min[k] - origin[k]) / spacing).ceil().max(0.0));
        let end = [0, 1, 2].map(|k| ((r.max[k] - origin[k]) / spacing).floor() + 1.0);
        for k in 0..3 {
            let (a, b) = (first[k] as usize, (end[k].max(0.0) as usize).min(full[k]));
            if a < b {
                lo[k] = lo[k].min(a);
                hi[k] = hi[k].max(b);
            }
        }
    }
    for k in 0..3 {
        hi[k] = hi[k].max(lo[k].min(full[k]));
        lo[k] = lo[k].min(hi[k]);
    }
    (lo, hi)
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
    // The lattice over the blocks' bounds ...
    let full: [usize; 3] =
        [0, 1, 2].map(|k| ((bounds.max[k] - bounds.min[k]) / spacing).ceil().max(1.0) as usize);
    let lattice_origin: [f64; 3] = [0, 1, 2].map(|k| {
        let used = full[k] as f64 * spacing;
        bounds.min[k] + 0.5 * (bounds.max[k] - bounds.min[k] - used) + 0.5 * spacing
    });
    // ... laid out whole, or over the lattice points in the dynamic objects' regions — and,
    // with `probe_volume: always`, around every clutter object (the MRT baseline shades
    // clutter from the probes) — each grown by one spacing so a lookup inside finds the 8
    // grid points around it.
    let shade_clutter = scene.settings.probe_volume == ProbeVolumeMode::Always;
    let regions = scene.probe_regions().map(|mut regions| {
        if shade_clutter {
            regions.extend(g.clutter_shapes.iter().map(|c| Aabb {
                min: c.bounds[0].map(|x| x - spacing),
                max: c.bounds[1].map(|x| x + spacing),
            }));
        }
        regions
    });
    let (lo, hi) = match &regions {
        None => ([0; 3], full),
        Some(regions) => lattice_span(regions, lattice_origin, spacing, full),
    };
    let dims: [usize; 3] = [0, 1, 2].map(|k| (hi[k] - lo[k]).max(1));
    let origin: [f64; 3] = [0, 1, 2].map(|k| lattice_origin[k] + lo[k] as f64 * spacing);
    let in_regions = |p: [f64; 3]| {
        regions.as_ref().is_none_or(|rs| {
            rs.iter()
                .any(|r| (0..3).all(|k| p[k] >= r.min[k] && p[k] <= r.max[k]))
        })
    };
    // Only blocks meeting the laid-out box can hold one of its points.
    let (box_lo, box_hi) = (
        origin,
        [0, 1, 2].map(|k| origin[k] + (dims[k] - 1) as f64 * spacing),
    );
    let blocks: Vec<_> = scene
        .blocks
        .iter()
        .filter(|b| (0..3).all(|k| b.min[k] < box_hi[k] && b.max[k] > box_lo[k]))
        .collect();
    let inside_block = |p: [f64; 3]| {
        blocks
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
    // Probe positions and their lattice indices (which key their ray streams, so a probe's
    // operator is the same whichever part of the lattice is laid out).
    let mut positions = Vec::new();
    let mut lattice_index = Vec::new();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let at = [lo[0] + i, lo[1] + j, lo[2] + k];
                let p = [0, 1, 2].map(|a| lattice_origin[a] + at[a] as f64 * spacing);
                if (0..3).all(|a| at[a] < hi[a])
                    && in_regions(p)
                    && inside_block(p)
                    && !inside_clutter(p)
                {
                    slot[(k * dims[1] + j) * dims[0] + i] = positions.len() as u32;
                    positions.push(p);
                    lattice_index.push(((at[2] * full[1] + at[1]) * full[0] + at[0]) as u64);
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
            let key = stream_key(scene.settings.seed, Purpose::Probes, lattice_index[p]);
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
