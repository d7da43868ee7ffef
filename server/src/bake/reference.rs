//! The brute-force reference: one-bounce indirect light on the full geometry (blocks, clutter,
//! posed dynamic objects), with direct light evaluated exactly at every hit point by shadow rays.
//!
//! `L_ind(x) = ρ(x) · mean_i L_d(hit_i)` over cosine-weighted rays (papers/README.md), and
//! `L_d(y) = ρ(y)/π · Σ_l I_l · cosθ_l / r_l² · V(y, l)` with the geometric normal facing the
//! ray (surfaces are two-sided, as in the Mitsuba ground truth). Quasi-random and seeded; its own
//! convergence is tested.
//!
//! Invariant: texel records come out in geometry order with the same surface names and indices
//! as a bundle of the same scene and settings, so `compare` can match them.

use std::f64::consts::PI;

use rayon::prelude::*;

use lightfarm_proto::lights::Light;
use lightfarm_proto::result::{ResultFile, TexelRecord};

use super::geometry::{Geometry, Primitive};
use super::one_bounce::PURPOSE_REFERENCE;
use super::sampling::{
    sample_cosine_hemisphere, sample_uniform_hemisphere, sobol_2d, stream_key, to_world,
};
use super::tracer::Tracer;

/// Stream purposes of the brute-force SH references (texel index is the stream).
const PURPOSE_REFERENCE_SH: u64 = 62;
const PURPOSE_REFERENCE_IRRADIANCE: u64 = 63;

/// Direct outgoing radiance at `p` with normal `n` (lit side) and albedo `albedo`.
pub fn direct_radiance(
    tracer: &Tracer,
    lights: &[Light],
    p: [f64; 3],
    n: [f64; 3],
    albedo: [f64; 3],
    min_r2: f64,
) -> [f64; 3] {
    let mut out = [0.0; 3];
    for light in lights {
        let d = [
            light.position[0] - p[0],
            light.position[1] - p[1],
            light.position[2] - p[2],
        ];
        let dist2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        let r2 = dist2.max(min_r2);
        let cos = (d[0] * n[0] + d[1] * n[1] + d[2] * n[2]) / dist2.sqrt().max(1e-300);
        if cos <= 0.0 || tracer.occluded(p, light.position) {
            continue;
        }
        for c in 0..3 {
            out[c] += albedo[c] / PI * light.intensity[c] * cos / r2;
        }
    }
    out
}

/// Reference direct and indirect radiance for every texel of `g`.
pub fn reference(
    g: &Geometry,
    lights: &[Light],
    rays: u32,
    seed: u64,
    progress: &(dyn Fn(u64) + Sync),
) -> ResultFile {
    let tracer = Tracer::new(g.primitives.clone(), g.scale());
    let min_r2 = (1e-4 * g.scale()).powi(2);
    let sign = |s: u32| g.surfaces[s as usize].normal_sign;
    let texels: Vec<TexelRecord> = (0..g.texels.len())
        .into_par_iter()
        .map(|x| {
            let texel = &g.texels[x];
            let direct = direct_radiance(
                &tracer,
                lights,
                texel.position,
                texel.normal,
                texel.albedo,
                min_r2,
            );
            let key = stream_key(seed, PURPOSE_REFERENCE, x as u64);
            let mut sum = [0.0; 3];
            for i in 0..rays {
                let d = to_world(sample_cosine_hemisphere(sobol_2d(key, i)), texel.normal);
                let Some(hit) = tracer.closest(texel.position, d, f64::INFINITY, &sign) else {
                    continue;
                };
                let albedo = match tracer.primitives()[hit.primitive as usize] {
                    Primitive::Rect { albedo, .. } | Primitive::Triangle { albedo, .. } => albedo,
                };
                let l = direct_radiance(&tracer, lights, hit.point, hit.normal, albedo, min_r2);
                for c in 0..3 {
                    sum[c] += l[c];
                }
            }
            progress(1);
            let surface = &g.surfaces[texel.surface as usize];
            TexelRecord {
                surface: surface.name.clone(),
                index: texel.index,
                position: texel.position,
                normal: texel.normal,
                albedo: texel.albedo,
                direct,
                indirect: [0, 1, 2].map(|c| texel.albedo[c] * sum[c] / rays as f64),
            }
        })
        .collect();
    ResultFile { texels }
}

/// Exact direct radiance leaving the first surface hit along `o + t·d` (0 on a miss).
fn radiance_along(
    tracer: &Tracer,
    g: &Geometry,
    lights: &[Light],
    o: [f64; 3],
    d: [f64; 3],
    min_r2: f64,
) -> [f64; 3] {
    let sign = |s: u32| g.surfaces[s as usize].normal_sign;
    let Some(hit) = tracer.closest(o, d, f64::INFINITY, &sign) else {
        return [0.0; 3];
    };
    let albedo = match tracer.primitives()[hit.primitive as usize] {
        Primitive::Rect { albedo, .. } | Primitive::Triangle { albedo, .. } => albedo,
    };
    direct_radiance(tracer, lights, hit.point, hit.normal, albedo, min_r2)
}

/// Brute-force SH incident radiance (`lightfarm_proto::sh`, world frame) at texel `x` of `g`:
/// `L_lm = (2π/N) Σ Y_lm(ω_i) L_d(hit_i)` over N uniform directions of the texel's geometric
/// hemisphere, with direct light evaluated exactly at every hit (one bounce, as [`reference`]).
/// Returns `[channel][lm]`.
pub fn reference_incident_sh(
    g: &Geometry,
    tracer: &Tracer,
    lights: &[Light],
    x: usize,
    rays: u32,
    seed: u64,
) -> [[f64; lightfarm_proto::sh::SH_COEFFS]; 3] {
    let texel = &g.texels[x];
    let min_r2 = (1e-4 * g.scale()).powi(2);
    let key = stream_key(seed, PURPOSE_REFERENCE_SH, x as u64);
    let weight = 2.0 * PI / rays as f64;
    let mut out = [[0.0; lightfarm_proto::sh::SH_COEFFS]; 3];
    for i in 0..rays {
        let d = to_world(sample_uniform_hemisphere(sobol_2d(key, i)), texel.normal);
        let l = radiance_along(tracer, g, lights, texel.position, d, min_r2);
        let y = lightfarm_proto::sh::sh_basis(d);
        for c in 0..3 {
            for (o, y_lm) in out[c].iter_mut().zip(y) {
                *o += weight * l[c] * y_lm;
            }
        }
    }
    out
}

/// Brute-force irradiance at texel `x` for a perturbed unit normal `n` (a normal map's):
/// `E = ∫ L(ω) (ω·n)₊ dω` over directions above the texel's geometric surface only (below it
/// the ray would start inside the wall), by cosine-weighted rays about `n`.
pub fn reference_irradiance(
    g: &Geometry,
    tracer: &Tracer,
    lights: &[Light],
    x: usize,
    n: [f64; 3],
    rays: u32,
    seed: u64,
) -> [f64; 3] {
    let texel = &g.texels[x];
    let min_r2 = (1e-4 * g.scale()).powi(2);
    let key = stream_key(seed, PURPOSE_REFERENCE_IRRADIANCE, x as u64);
    let mut sum = [0.0; 3];
    for i in 0..rays {
        let d = to_world(sample_cosine_hemisphere(sobol_2d(key, i)), n);
        let above: f64 = (0..3).map(|k| d[k] * texel.normal[k]).sum();
        if above <= 0.0 {
            continue;
        }
        let l = radiance_along(tracer, g, lights, texel.position, d, min_r2);
        for c in 0..3 {
            sum[c] += l[c];
        }
    }
    sum.map(|s| PI * s / rays as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::lights::LightKind;
    use lightfarm_proto::scene::Aabb;
    use lightfarm_proto::Face;

    fn closed_box(albedo: f64, t: usize) -> Geometry {
        let mut g = Geometry::default();
        g.add_block(
            0,
            "b",
            &Aabb {
                min: [0.0; 3],
                max: [2.0, 2.0, 2.0],
            },
            &Face::ALL,
            |_| [albedo; 3],
            t,
        );
        g
    }

    fn light(p: [f64; 3], i: f64) -> Light {
        Light {
            kind: LightKind::Point,
            position: p,
            intensity: [i; 3],
        }
    }

    /// In a closed white box, the flux reflected once equals ρ times the flux received, so the
    /// area-weighted mean indirect radiance is ρ² Φ_total / (π A) where Φ_total = 4π I.
    #[test]
    fn closed_box_one_bounce_conserves_energy() {
        let rho = 0.5;
        let g = closed_box(rho, 8);
        let lights = [light([1.0, 1.0, 1.0], 1.0)];
        let result = reference(&g, &lights, 1024, 3, &|_| {});
        let area = 6.0 * 4.0;
        let texel_area = area / g.texels.len() as f64;
        // Outgoing flux of the first bounce: Σ π L_ind A_texel; it equals ρ · (flux of direct
        // light leaving surfaces) = ρ · ρ · 4π I.
        let flux: f64 = result
            .texels
            .iter()
            .map(|t| PI * t.indirect[0] * texel_area)
            .sum();
        let expected = rho * rho * 4.0 * PI;
        assert!(
            (flux - expected).abs() < 0.03 * expected,
            "{flux} vs {expected}"
        );
        // Energy bound: indirect ≤ albedo × max direct seen.
        let max_direct = result
            .texels
            .iter()
            .map(|t| t.direct[0])
            .fold(0.0, f64::max);
        assert!(result
            .texels
            .iter()
            .all(|t| t.indirect[0] <= rho * max_direct + 1e-12));
    }

    #[test]
    fn error_halves_as_rays_quadruple() {
        let g = closed_box(0.7, 2);
        let lights = [light([0.5, 1.5, 0.7], 2.0), light([1.6, 0.4, 1.2], 1.0)];
        let truth = reference(&g, &lights, 1 << 16, 99, &|_| {});
        let mut errors = Vec::new();
        for rays in [64u32, 256, 1024] {
            let mut e = 0.0;
            for seed in 0..4 {
                let r = reference(&g, &lights, rays, seed, &|_| {});
                e += lightfarm_proto::result::compare(&r, &truth).relative_l2;
            }
            errors.push(e / 4.0);
        }
        for w in errors.windows(2) {
            assert!(
                w[1] <= 0.6 * w[0],
                "error must at least halve as rays quadruple: {errors:?}"
            );
        }
    }

    #[test]
    fn a_light_on_a_surface_gives_finite_values() {
        let g = closed_box(0.5, 4);
        let lights = [light([1.0, 0.0, 1.0], 1.0)];
        let result = reference(&g, &lights, 64, 0, &|_| {});
        assert!(result.texels.iter().all(|t| t
            .direct
            .iter()
            .chain(&t.indirect)
            .all(|x| x.is_finite())));
    }
}
