//! SH (vector) responses for normal-mapped surfaces (DRT paper 000 §5, "vector-valued ΔU_b,
//! ΔU_c and C_b"): per lit texel, the order-2 SH projection of its incident radiance as a linear
//! map from the coefficient vectors the scalar runtime already computes (blocks' `b`, clutter
//! objects' `c`), so a client can shade any perturbed normal `n'` with `ρ/π · E(n')`.
//!
//! **How (our design, not the paper's operator algebra).** MRT has no vector basis, so instead
//! of adding a vector `U_b⃗` to the shape operators plus vector deltas, every lit texel x gathers
//! directly against the real geometry (blocks and clutter):
//!
//! `L_lm(x) = (2π/N) Σ_i Y_lm(ω_i) · L(hit_i)`, ω_i uniform on x's geometric hemisphere,
//!
//! with `L(hit)` the implicit radiance of the texel hit (`sh::gather`: `L_imp^A b_A` on a block
//! texel, `B_j c_j` on a clutter texel). Directions below the hemisphere see x's own surface and
//! carry nothing. Grouped by source exactly like the scalar `DeltaEntry`s, the paper's operators
//! are pieces of what we store: on block texels, rows from a block's `b` are `U_b⃗ + transport⃗ +
//! ΔU_b⃗` combined (own block, neighbours through openings, minus what clutter occludes) and rows
//! from a clutter `c` are `ΔU_c⃗`; on clutter texels, rows from `b` are `C_b⃗` and rows from
//! another clutter object's `c` its bounce. Exact to one bounce (the scalar operators' order),
//! occlusion and interreflection included because the rays see the real geometry.
//!
//! **Estimator.** Uniform hemisphere directions (seeded scrambled Sobol', per texel stream): the
//! weight `2π · Y_lm` is bounded (|Y_lm| ≤ 1.093), so each coefficient's variance is at most
//! `(2π · 1.093 · max L)² / N`. Cosine-weighted rays would share the scalar pass's sampling but
//! need `π · Y_lm / cos θ`, unbounded at grazing angles (infinite variance for l ≥ 1 terms).
//!
//! **Compression (model only what the scene needs).** Per receiving object (block or clutter box)
//! and source, the `9·texels × width` response `M` is truncated by SVD to the smallest rank
//! keeping `1 − tolerance` of the squared Frobenius norm of `W M` (`low_rank`), where `W`
//! weights coefficient lm by `Â_l/π` (1, 2/3, 1/4 per band): the error is measured in what
//! the client reads, irradiance, not in the radiance coefficients (band 2 counts a quarter).
//! `M ≈ Y Z` with `Y = W⁻¹ U_k Σ_k` (9·texels × k), `Z = V_kᵀ` (k × width). Sources no ray of an
//! object reached get no entry.
//!
//! Frames and units: world frame, y up (`lightfarm_proto::sh`); radiance per unit coefficient.
//! Invariants: albedo-free; every random number is a function of (seed, purpose, texel, ray);
//! texels run in parallel but each depends on its own stream only, and each SVD runs
//! sequentially, so the result is bit-identical at any thread count. Buried texels (DRT) get no
//! rows (they are dark in the scalar output too).

use std::collections::BTreeMap;

use faer::Mat;
use rayon::prelude::*;

use lightfarm_proto::bundle::DeltaSource;
use lightfarm_proto::scene::Scene;
use lightfarm_proto::sh::{irradiance_weights, sh_basis, SH_COEFFS};

use crate::bake::drt::build::ClutterProjection;
use crate::bake::drt::lit_source::LitSource;
use crate::bake::math::low_rank::{truncated_svd, LowRankError};
use crate::bake::math::sampling::{
    sample_uniform_hemisphere, sobol_2d, stream_key, to_world, Purpose,
};
use crate::bake::mrt::shape::ShapeOperators;
use crate::bake::scene::geometry::{Geometry, SurfaceOwner};
use crate::bake::sh::gather::{implicit_source_hit, sh_rows};
use crate::bake::tracer::Tracer;

/// One receiving object's response to one source, factored: `M ≈ y · z`.
pub struct ShResponseBlock {
    /// Global texel indices, ascending.
    pub texels: Vec<u32>,
    pub source: DeltaSource,
    /// 9·texels × k; row `9·i + lm`.
    pub y: Mat<f64>,
    /// k × width of the source.
    pub z: Mat<f64>,
}

/// Figures about the build.
#[derive(Clone, Debug, Default)]
pub struct ShResponseStats {
    /// Texels with at least one row, and lit texels skipped because DRT buried them.
    pub texels_with_rows: usize,
    pub buried_texels: usize,
    pub entries: usize,
    /// Σ over entries of the kept rank, and of the source width (what dense storage would use).
    pub kept_rank: usize,
    pub full_width: usize,
    /// Values stored (`Y` and `Z` of every entry), and what the unfactored `M`s would hold.
    pub stored_values: usize,
    pub dense_values: usize,
    /// Largest fraction of squared Frobenius norm one entry's truncation dropped.
    pub max_dropped_energy: f64,
}

/// All SH responses of a scene.
pub struct ShResponseOps {
    pub entries: Vec<ShResponseBlock>,
    pub stats: ShResponseStats,
}

/// Which object owns global texel `x`: `(0, block)` or `(1, scene clutter index)`.
fn owner_of(g: &Geometry, x: usize) -> (u8, u32) {
    match g.surfaces[g.texels[x].surface as usize].owner {
        SurfaceOwner::Block { block, .. } => (0, block as u32),
        SurfaceOwner::ClutterBox { clutter, .. } | SurfaceOwner::ClutterMesh { clutter, .. } => {
            (1, clutter as u32)
        }
    }
}

/// The 9 SH rows per source of texel `x`'s incident radiance.
#[allow(clippy::too_many_arguments)]
fn texel_response(
    g: &Geometry,
    tracer: &Tracer,
    shapes: &[&ShapeOperators],
    clutter: &[ClutterProjection],
    projection_of: &[Option<usize>],
    rays: u32,
    seed: u64,
    x: usize,
) -> BTreeMap<LitSource, [Vec<f64>; SH_COEFFS]> {
    let texel = &g.texels[x];
    let key = stream_key(seed, Purpose::ShResponse, x as u64);
    let weight = 2.0 * std::f64::consts::PI / rays as f64;
    let mut by_texel: BTreeMap<(LitSource, usize), [f64; SH_COEFFS]> = BTreeMap::new();
    for i in 0..rays {
        let d = to_world(sample_uniform_hemisphere(sobol_2d(key, i)), texel.normal);
        if let Some(hit) = implicit_source_hit(g, tracer, projection_of, texel.position, d) {
            let acc = by_texel.entry(hit).or_insert([0.0; SH_COEFFS]);
            for (a, y) in acc.iter_mut().zip(sh_basis(d)) {
                *a += weight * y;
            }
        }
    }
    sh_rows(&by_texel, shapes, clutter)
}

/// Builds the SH responses of every lit texel of `g` (blocks and clutter, meshes included). `clutter` and
/// `projection_of` are the DRT clutter bases (empty without clutter); `buried` the texels DRT
/// flagged (ascending).
pub fn build_sh_responses(
    scene: &Scene,
    g: &Geometry,
    shapes: &[&ShapeOperators],
    clutter: &[ClutterProjection],
    projection_of: &[Option<usize>],
    buried: &[u32],
    progress: &(dyn Fn(u64) + Sync),
) -> Result<ShResponseOps, LowRankError> {
    let settings = &scene.settings;
    let tracer = Tracer::new(g.primitives.clone(), g.scale());
    let mut stats = ShResponseStats::default();
    let lit: Vec<usize> = (0..g.texels.len())
        .filter(|x| buried.binary_search(&(*x as u32)).is_err())
        .collect();
    stats.buried_texels = g.texels.len() - lit.len();
    let responses: Vec<BTreeMap<LitSource, [Vec<f64>; SH_COEFFS]>> = lit
        .par_iter()
        .map(|&x| {
            let r = texel_response(
                g,
                &tracer,
                shapes,
                clutter,
                projection_of,
                settings.rays_per_texel,
                settings.seed,
                x,
            );
            progress(1);
            r
        })
        .collect();

    // Group by (receiving object, source); texels stay ascending within a group.
    type Group = Vec<(u32, [Vec<f64>; SH_COEFFS])>;
    let mut groups: BTreeMap<((u8, u32), LitSource), Group> = BTreeMap::new();
    for (&x, response) in lit.iter().zip(responses) {
        if !response.is_empty() {
            stats.texels_with_rows += 1;
        }
        let owner = owner_of(g, x);
        for (source, rows) in response {
            groups
                .entry((owner, source))
                .or_default()
                .push((x as u32, rows));
        }
    }
    let groups: Vec<(LitSource, Group)> = groups
        .into_iter()
        .map(|((_, source), group)| (source, group))
        .collect();

    // One truncated SVD per group (each sequential; groups in parallel, order kept).
    let band_weight = irradiance_weights().map(|a| a / std::f64::consts::PI);
    let factored: Vec<Result<Option<(ShResponseBlock, f64, usize)>, LowRankError>> = groups
        .par_iter()
        .map(|(source, group)| {
            let width = group[0].1[0].len();
            // Truncate what the client reads, irradiance: coefficient lm weighted by Â_l/π.
            let m = Mat::from_fn(SH_COEFFS * group.len(), width, |i, j| {
                band_weight[i % SH_COEFFS] * group[i / SH_COEFFS].1[i % SH_COEFFS][j]
            });
            let svd = truncated_svd(m.as_ref(), settings.tolerance)?;
            let k = svd.s.len();
            if k == 0 {
                return Ok(None);
            }
            let y = Mat::from_fn(m.nrows(), k, |i, j| {
                svd.u[(i, j)] * svd.s[j] / band_weight[i % SH_COEFFS]
            });
            let z = Mat::from_fn(k, width, |i, j| svd.v[(j, i)]);
            Ok(Some((
                ShResponseBlock {
                    texels: group.iter().map(|(x, _)| *x).collect(),
                    source: (*source).into(),
                    y,
                    z,
                },
                svd.dropped_energy,
                width,
            )))
        })
        .collect();
    let mut entries = Vec::new();
    for f in factored {
        if let Some((block, dropped, width)) = f? {
            stats.kept_rank += block.z.nrows();
            stats.full_width += width;
            stats.stored_values += block.y.nrows() * block.y.ncols() + block.z.nrows() * width;
            stats.dense_values += block.y.nrows() * width;
            stats.max_dropped_energy = stats.max_dropped_energy.max(dropped);
            entries.push(block);
        }
    }
    stats.entries = entries.len();
    Ok(ShResponseOps { entries, stats })
}
