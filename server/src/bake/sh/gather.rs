//! SH gathering of the runtime's implicit radiance along rays, shared by the probe volume
//! (`probe_volume`, U_dyn) and the per-texel SH responses (`sh_response`).
//!
//! A ray that lands on the lit side of a block texel sees `L_imp^A b_A` (row of the block's
//! implicit lights), on a box-clutter texel `B_j c_j` (row of the clutter basis): the radiance of
//! direct-lit surfaces as the coefficient vectors the client computes, so whatever is gathered
//! from it is one-bounce light and linear in `b` and `c`. Misses, back sides and geometry without
//! texels (mesh clutter) see nothing.
//!
//! Units: radiance per unit of the coefficients; SH per `lightfarm_proto::sh` (world frame).
//! Invariant: pure functions of their inputs (no randomness here); sums run in ascending
//! (source, texel) order, so callers that keep their own order are bit-reproducible.

use std::collections::BTreeMap;

use glam::DVec3;
use lightfarm_proto::sh::SH_COEFFS;

use crate::bake::drt::build::ClutterProjection;
use crate::bake::drt::lit_source::LitSource;
use crate::bake::mrt::shape::ShapeOperators;
use crate::bake::scene::geometry::{Geometry, Primitive, SurfaceOwner};
use crate::bake::tracer::Tracer;

/// The lit texel the ray `o + t·d` lands on, as (source, texel index local to the source), or
/// None (miss, back side, no texels, clutter without a basis). `projection_of[c]` maps a scene
/// clutter index to its DRT clutter index.
pub fn implicit_source_hit(
    g: &Geometry,
    tracer: &Tracer,
    projection_of: &[Option<usize>],
    o: [f64; 3],
    d: [f64; 3],
) -> Option<(LitSource, usize)> {
    let sign = |s: u32| g.surfaces[s as usize].normal_sign;
    let hit = tracer.closest(o, d, f64::INFINITY, &sign)?;
    let (s, t) = match tracer.primitives()[hit.primitive as usize] {
        Primitive::Rect {
            surface: Some(s), ..
        } if hit.front => (s, g.texel_at(s, hit.point)),
        Primitive::Triangle {
            v,
            lightmap: Some(m),
            ..
        } => {
            // Mesh clutter: its lit (counter-clockwise) side only.
            let [v0, v1, v2] = v.map(DVec3::from);
            let n = (v1 - v0).cross(v2 - v0);
            if DVec3::from(hit.normal).dot(n) <= 0.0 {
                return None;
            }
            let surface = g.mesh_atlases[m.atlas as usize].1;
            (surface, g.mesh_texel_at(m, hit.point))
        }
        _ => return None,
    };
    match g.surfaces[s as usize].owner {
        SurfaceOwner::Block { block, .. } => Some((
            LitSource::Block(block as u32),
            t - g.block_texels[block].start,
        )),
        SurfaceOwner::ClutterBox { clutter: c, .. }
        | SurfaceOwner::ClutterMesh { clutter: c, .. } => projection_of
            .get(c)
            .copied()
            .flatten()
            .map(|j| (LitSource::Clutter(j as u32), t - g.clutter_texels[c].start)),
    }
}

/// Row `local` of the source's implicit lights: `L_imp` of the block, or the basis of the DRT
/// clutter object.
pub fn implicit_row(
    shapes: &[&ShapeOperators],
    clutter: &[ClutterProjection],
    key: LitSource,
    local: usize,
) -> Vec<f64> {
    let m = match key {
        LitSource::Block(b) => &shapes[b as usize].l_imp,
        LitSource::Clutter(c) => &clutter[c as usize].basis.basis,
    };
    (0..m.ncols()).map(|j| m[(local, j)]).collect()
}

/// Turns SH-weighted hit sums (`(source, local texel) → Σ_rays w·Y_lm(ω)`) into 9 rows per
/// source: `rows[source][lm] = Σ_texels sum[lm] · implicit_row(source, texel)`.
pub fn sh_rows(
    by_texel: &BTreeMap<(LitSource, usize), [f64; SH_COEFFS]>,
    shapes: &[&ShapeOperators],
    clutter: &[ClutterProjection],
) -> BTreeMap<LitSource, [Vec<f64>; SH_COEFFS]> {
    let mut out: BTreeMap<LitSource, [Vec<f64>; SH_COEFFS]> = BTreeMap::new();
    for (&(key, local), y) in by_texel {
        let row = implicit_row(shapes, clutter, key, local);
        let acc = out
            .entry(key)
            .or_insert_with(|| std::array::from_fn(|_| vec![0.0; row.len()]));
        for (lm, y_lm) in y.iter().enumerate() {
            for (a, v) in acc[lm].iter_mut().zip(&row) {
                *a += y_lm * v;
            }
        }
    }
    out
}
