//! The lighting prior P of a shape (DRT §3.2; MRT): a low-dimensional basis for the direct
//! light a shape's texels can plausibly receive.
//!
//! Lights are placed quasi-randomly (i) in the block volume clipped to the scene's light regions
//! and (ii) in a slab beyond each opening, so light arriving through an opening is representable
//! (paper 002 §3.2.1 places entry points from the same a-priori knowledge). Each light gives an
//! albedo-free pattern `cosθ / r² · V` over the texels, normalised to unit length so every light
//! position weighs the same.
//!
//! Design (ours, the MRT paper is not available): the prior is block-diagonal over faces —
//! one SVD per closed face — so its span is closed under per-face scaling. Direct light on a face
//! with albedo ρ_f is `ρ_f ·` (albedo-free pattern), and a block with coloured walls is therefore
//! represented exactly as well as a grey one: shape operators never depend on albedo.
//! `P` is texels × n, `S` holds the per-face singular values (n), both in f64.

use faer::Mat;

use crate::bake::math::low_rank::{truncated_svd, LowRankError};
use crate::bake::math::sampling::{halton_point_in, stream_key, Purpose};
use crate::bake::scene::geometry::{Geometry, Texel};
use lightfarm_proto::scene::Aabb;
use lightfarm_proto::Face;

/// The prior basis.
pub struct LightingPrior {
    /// texels × n, orthonormal columns, block-diagonal by face.
    pub basis: Mat<f64>,
    /// n singular values matching `basis`' columns.
    pub singular_values: Vec<f64>,
    /// Light positions used (local frame).
    pub lights: Vec<[f64; 3]>,
    /// Energy fraction dropped, per face.
    pub dropped_energy: Vec<f64>,
}

/// Where prior lights go, in the shape's local frame (block spans `[0, extent]`).
pub fn prior_light_positions(
    extent: [f64; 3],
    open: &[Face],
    region: Option<Aabb>,
    count: usize,
    seed: u64,
) -> Vec<[f64; 3]> {
    let block = Aabb {
        min: [0.0; 3],
        max: extent,
    };
    let mut boxes: Vec<Aabb> = Vec::new();
    let volume = match region {
        Some(r) => r.intersection(&block),
        None => Some(block),
    };
    let depth = extent.iter().cloned().fold(0.0, f64::max);
    let slabs: Vec<Aabb> = open
        .iter()
        .map(|f| {
            let mut s = block;
            let a = f.axis();
            for k in 0..3 {
                if k != a {
                    s.min[k] -= 0.5 * depth;
                    s.max[k] += 0.5 * depth;
                }
            }
            if f.is_max_side() {
                s.min[a] = extent[a];
                s.max[a] = extent[a] + depth;
            } else {
                s.min[a] = -depth;
                s.max[a] = 0.0;
            }
            s
        })
        .collect();
    // Half the lights inside (if there is a volume to light), half shared by the openings.
    let inside = match (&volume, slabs.is_empty()) {
        (Some(_), true) => count,
        (Some(_), false) => count / 2,
        (None, false) => 0,
        (None, true) => count,
    };
    let mut out = Vec::with_capacity(count);
    let inner = volume.unwrap_or(block);
    boxes.push(inner);
    for i in 0..inside {
        out.push(halton_point_in(
            &inner,
            i as u64,
            stream_key(seed, Purpose::PriorInside, 0),
        ));
    }
    let rest = count - inside;
    for (k, slab) in slabs.iter().enumerate() {
        let n = rest / slabs.len() + usize::from(k < rest % slabs.len());
        for i in 0..n {
            out.push(halton_point_in(
                slab,
                i as u64,
                stream_key(seed, Purpose::PriorSlabs, k as u64 + 1),
            ));
        }
    }
    out
}

/// Albedo-free direct pattern of a point light at `light` over the texels of a lone shape
/// (an empty convex box): `cosθ / r²`, visible unless the light is outside and the segment
/// leaves the box through a closed face.
pub fn light_pattern(
    geometry: &Geometry,
    extent: [f64; 3],
    open: &[Face],
    light: [f64; 3],
    out: &mut [f64],
) {
    let min_r2 = (1e-3 * extent.iter().cloned().fold(0.0, f64::max)).powi(2);
    let inside = (0..3).all(|k| light[k] >= 0.0 && light[k] <= extent[k]);
    for (t, texel) in geometry.texels.iter().enumerate() {
        let unshadowed = unshadowed_pattern(texel, light, min_r2);
        let visible = unshadowed > 0.0
            && (inside || exits_through_opening(texel.position, light, extent, open));
        out[t] = if visible { unshadowed } else { 0.0 };
    }
}

/// Albedo-free, unshadowed direct pattern `max(cosθ, 0) / max(r², min_r2)` of a unit point light
/// at `light` on `texel` (shared by the shape prior and the clutter prior).
pub fn unshadowed_pattern(texel: &Texel, light: [f64; 3], min_r2: f64) -> f64 {
    let d = [
        light[0] - texel.position[0],
        light[1] - texel.position[1],
        light[2] - texel.position[2],
    ];
    let r2 = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).max(min_r2);
    let cos =
        (d[0] * texel.normal[0] + d[1] * texel.normal[1] + d[2] * texel.normal[2]) / r2.sqrt();
    if cos <= 0.0 {
        0.0
    } else {
        cos / r2
    }
}

/// Does the segment from `p` (on the box boundary) to `q` (outside) leave the box through an
/// open face?
fn exits_through_opening(p: [f64; 3], q: [f64; 3], extent: [f64; 3], open: &[Face]) -> bool {
    let d = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
    let mut best = (f64::INFINITY, None);
    for face in Face::ALL {
        let a = face.axis();
        if d[a] == 0.0 {
            continue;
        }
        let plane = if face.is_max_side() { extent[a] } else { 0.0 };
        let s = (plane - p[a]) / d[a];
        let leaving = if face.is_max_side() {
            d[a] > 0.0
        } else {
            d[a] < 0.0
        };
        if leaving && s > 1e-12 && s < best.0 {
            best = (s, Some(face));
        }
    }
    match best.1 {
        Some(face) => open.contains(&face),
        None => false,
    }
}

/// Builds the prior: patterns of `lights`, then one truncated SVD per closed face.
pub fn build_prior(
    geometry: &Geometry,
    extent: [f64; 3],
    open: &[Face],
    lights: Vec<[f64; 3]>,
    tolerance: f64,
) -> Result<LightingPrior, LowRankError> {
    let n_texels = geometry.texels.len();
    let mut patterns = Mat::<f64>::zeros(n_texels, lights.len());
    let mut column = vec![0.0; n_texels];
    for (j, light) in lights.iter().enumerate() {
        light_pattern(geometry, extent, open, *light, &mut column);
        let norm = column.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm > 0.0 {
            for (i, x) in column.iter().enumerate() {
                patterns[(i, j)] = x / norm;
            }
        }
    }
    let mut columns: Vec<(usize, Vec<f64>, f64)> = Vec::new(); // (texel offset, column, σ)
    let mut dropped = Vec::new();
    for surface in &geometry.surfaces {
        let rows = surface.texel_offset..surface.texel_offset + surface.t * surface.t;
        let block = patterns.subrows(rows.start, rows.len());
        let svd = truncated_svd(block, tolerance)?;
        dropped.push(svd.dropped_energy);
        for k in 0..svd.s.len() {
            columns.push((
                rows.start,
                (0..rows.len()).map(|i| svd.u[(i, k)]).collect(),
                svd.s[k],
            ));
        }
    }
    let mut basis = Mat::<f64>::zeros(n_texels, columns.len());
    let mut singular_values = Vec::with_capacity(columns.len());
    for (j, (offset, col, s)) in columns.into_iter().enumerate() {
        for (i, x) in col.into_iter().enumerate() {
            basis[(offset + i, j)] = x;
        }
        singular_values.push(s);
    }
    Ok(LightingPrior {
        basis,
        singular_values,
        lights,
        dropped_energy: dropped,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn light_beyond_an_opening_lights_only_what_the_opening_lets_through() {
        let extent = [2.0, 2.0, 2.0];
        let mut g = Geometry::default();
        let open = [Face::PosX];
        let closed: Vec<Face> = Face::ALL.into_iter().filter(|f| *f != Face::PosX).collect();
        g.add_block(
            0,
            "s",
            &Aabb {
                min: [0.0; 3],
                max: extent,
            },
            &closed,
            |_| [1.0; 3],
            4,
        );
        let mut pattern = vec![0.0; g.texels.len()];
        // Straight out of the opening, far away: lights the -x wall, not the +y ceiling's
        // far texels behind the opening's rim.
        light_pattern(&g, extent, &open, [10.0, 1.0, 1.0], &mut pattern);
        let back_wall: f64 = pattern[0..16].iter().sum();
        assert!(back_wall > 0.0);
        // A light behind the closed -x wall lights nothing.
        light_pattern(&g, extent, &open, [-1.0, 1.0, 1.0], &mut pattern);
        assert!(pattern.iter().all(|x| *x == 0.0));
    }

    #[test]
    fn lights_fill_volume_and_slabs() {
        let lights = prior_light_positions([4.0, 3.0, 2.0], &[Face::NegZ], None, 100, 5);
        assert_eq!(lights.len(), 100);
        let inside = lights.iter().filter(|p| p[2] >= 0.0).count();
        assert_eq!(inside, 50);
        assert!(lights.iter().filter(|p| p[2] < 0.0).all(|p| p[2] >= -4.0));
    }
}
