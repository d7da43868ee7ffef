//! The basis for direct light on a clutter object (DRT §4.2): `c = T_d→c l_d`, `T_d→c = Bᵀ`
//! with `B` (texels × m) orthonormal.
//!
//! Two choices (`settings.clutter_basis`):
//! - `face_constant` — the paper's: one constant radiance per clutter face (m = faces; a mesh's
//!   faces are the charts of its lightmap atlas, `mesh_atlas`);
//! - `prior` — what the paper names as better: a lighting prior over the clutter's texels built
//!   from the same light distribution as the blocks' (lights in the blocks the clutter stands in
//!   and their neighbours, clipped to the light regions), with shadows from the real geometry.
//!   A box (or an uncoloured mesh) has one albedo, so direct light is `ρ · pattern` and one SVD
//!   over all its texels is albedo-invariant; a mesh with its own colours (glTF base colour)
//!   has direct light `ρ_c(x) · pattern` per channel c, so its prior holds the three
//!   albedo-weighted patterns of every light. Rank from the tolerance.
//!
//! Frames: world, metres. Invariant: `basis` has orthonormal columns.

use faer::Mat;
use rayon::prelude::*;

use lightfarm_proto::scene::{Aabb, ClutterBasis, Opening, Scene};

use crate::bake::math::low_rank::{truncated_column_basis, LowRankError};
use crate::bake::math::sampling::{halton_point_in, stream_key, Purpose};
use crate::bake::mrt::lighting_prior::unshadowed_pattern;
use crate::bake::scene::geometry::{Geometry, SurfaceOwner};
use crate::bake::tracer::Tracer;

/// An orthonormal basis over one clutter object's texels.
pub struct ClutterBasisOps {
    /// texels × m.
    pub basis: Mat<f64>,
    pub dropped_energy: f64,
}

/// Blocks whose volume meets `aabb`, and their neighbours one opening away.
fn nearby_blocks(scene: &Scene, openings: &[[Option<Opening>; 6]], aabb: &Aabb) -> Vec<usize> {
    let mut out: Vec<usize> = scene
        .blocks
        .iter()
        .enumerate()
        .filter(|(_, b)| (0..3).all(|k| b.min[k] <= aabb.max[k] && aabb.min[k] <= b.max[k]))
        .map(|(i, _)| i)
        .collect();
    let direct = out.clone();
    for b in direct {
        for o in openings[b].iter().flatten() {
            if let Opening::Neighbour { block, .. } = o {
                if !out.contains(block) {
                    out.push(*block);
                }
            }
        }
    }
    out.sort_unstable();
    out
}

/// The prior's light positions for clutter object `clutter`: quasi-random in the blocks it
/// stands in and their neighbours (volume-weighted), clipped to the light regions, never inside
/// the clutter itself.
pub fn prior_lights(
    scene: &Scene,
    openings: &[[Option<Opening>; 6]],
    clutter: usize,
    aabb: &Aabb,
) -> Vec<[f64; 3]> {
    let settings = &scene.settings;
    let blocks = nearby_blocks(scene, openings, aabb);
    let mut volumes: Vec<Aabb> = Vec::new();
    for b in &blocks {
        let block = scene.blocks[*b].aabb();
        if scene.light_regions.is_empty() {
            volumes.push(block);
        } else {
            volumes.extend(
                scene
                    .light_regions
                    .iter()
                    .filter_map(|r| r.intersection(&block)),
            );
        }
    }
    if volumes.is_empty() {
        volumes = blocks.iter().map(|b| scene.blocks[*b].aabb()).collect();
    }
    let weights: Vec<f64> = volumes
        .iter()
        .map(|v| v.extent().iter().product())
        .collect();
    let total: f64 = weights.iter().sum();
    let count = settings.prior_lights as usize;
    let key = stream_key(settings.seed, Purpose::ClutterPrior, clutter as u64);
    let mut lights = Vec::with_capacity(count);
    let mut acc = 0.0;
    for (v, w) in volumes.iter().zip(&weights) {
        let start = (acc / total * count as f64).round() as usize;
        acc += w;
        let end = (acc / total * count as f64).round() as usize;
        for i in start..end {
            let p = halton_point_in(v, i as u64, key);
            // Lights inside the clutter itself are not plausible.
            if !(0..3).all(|k| p[k] > aabb.min[k] && p[k] < aabb.max[k]) {
                lights.push(p);
            }
        }
    }
    lights
}

/// Builds the basis for clutter object `clutter` whose texels are `texels` in `g`.
#[allow(clippy::too_many_arguments)]
pub fn clutter_basis(
    scene: &Scene,
    openings: &[[Option<Opening>; 6]],
    g: &Geometry,
    tracer: &Tracer,
    clutter: usize,
    aabb: &Aabb,
    texels: std::ops::Range<usize>,
) -> Result<ClutterBasisOps, LowRankError> {
    let n = texels.len();
    let settings = &scene.settings;
    if settings.clutter_basis == ClutterBasis::FaceConstant {
        // One column per face (surface) of a box, per chart of a mesh's atlas.
        let mut faces: Vec<Vec<usize>> = Vec::new();
        for s in &g.surfaces {
            if s.texel_offset >= texels.start && s.texel_offset < texels.end {
                let start = s.texel_offset - texels.start;
                match s.owner {
                    SurfaceOwner::ClutterMesh { atlas, .. } => {
                        let atlas = &g.mesh_atlases[atlas].0;
                        let mut charts = vec![Vec::new(); atlas.n_charts];
                        for (k, t) in atlas.texels.iter().enumerate() {
                            charts[t.chart as usize].push(start + k);
                        }
                        faces.extend(charts.into_iter().filter(|c| !c.is_empty()));
                    }
                    _ => faces.push((start..start + s.n_texels).collect()),
                }
            }
        }
        let mut basis = Mat::<f64>::zeros(n, faces.len());
        for (j, rows) in faces.iter().enumerate() {
            for &i in rows {
                basis[(i, j)] = 1.0 / (rows.len() as f64).sqrt();
            }
        }
        return Ok(ClutterBasisOps {
            basis,
            dropped_energy: f64::NAN,
        });
    }
    let lights = prior_lights(scene, openings, clutter, aabb);
    let min_r2 = (1e-3 * g.scale()).powi(2);
    let albedo0 = g.texels[texels.start].albedo;
    let coloured = texels.clone().any(|t| g.texels[t].albedo != albedo0);
    let columns: Vec<Vec<f64>> = lights
        .par_iter()
        .flat_map_iter(|l| {
            let mut col: Vec<f64> = texels
                .clone()
                .map(|t| {
                    let texel = &g.texels[t];
                    let pattern = unshadowed_pattern(texel, *l, min_r2);
                    if pattern > 0.0 && !tracer.occluded(texel.position, *l) {
                        pattern
                    } else {
                        0.0
                    }
                })
                .collect();
            let weighted: Vec<Vec<f64>> = if coloured {
                (0..3)
                    .map(|c| {
                        col.iter()
                            .zip(texels.clone())
                            .map(|(x, t)| x * g.texels[t].albedo[c])
                            .collect()
                    })
                    .collect()
            } else {
                vec![std::mem::take(&mut col)]
            };
            weighted.into_iter().map(|mut col| {
                let norm = col.iter().map(|x| x * x).sum::<f64>().sqrt();
                if norm > 0.0 {
                    col.iter_mut().for_each(|x| *x /= norm);
                }
                col
            })
        })
        .collect();
    let patterns = Mat::from_fn(n, columns.len(), |i, j| columns[j][i]);
    let (basis, dropped_energy) = truncated_column_basis(patterns.as_ref(), settings.tolerance)?;
    Ok(ClutterBasisOps {
        basis,
        dropped_energy,
    })
}
