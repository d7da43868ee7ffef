//! The brute-force reference: indirect light on the full geometry (blocks, clutter, posed
//! dynamic objects), one bounce or all of them, with direct light evaluated exactly at every
//! path vertex by shadow rays (next-event estimation).
//!
//! One bounce: `L_ind(x) = ρ(x) · mean_i L_d(hit_i)` over cosine-weighted rays
//! (papers/README.md), and `L_d(y) = ρ(y)/π · Σ_l I_l · cosθ_l / r_l² · V(y, l)` with the
//! geometric normal facing the ray (surfaces are two-sided, as in the Mitsuba ground truth).
//!
//! All bounces (or N): each ray from x continues as a path `x → y₁ → y₂ → …` by cosine sampling
//! at every vertex; the estimator is `ρ(x) · Σ_k (Π_{j<k} ρ(y_j)) · L_d(y_k)`, the Neumann
//! series `L_ind = Σ_k (ρK)^k L_d` of the rendering equation for Lambertian surfaces, one
//! sample per term. From the third vertex on, Russian roulette ends a path with probability
//! `1 − q`, `q = min(max_c throughput_c ⋅ 1, 0.95)` relative to the path's start, and divides
//! the survivors by q, so the estimator stays unbiased and a path in a closed box of albedo
//! near 1 still ends. `indirect` is every bounce after the first light (the direct term
//! `L_d(x)` is `direct`).
//!
//! Sampling is seeded and quasi-random: the first direction is the texel's Owen-scrambled
//! Sobol' point, later directions are padded 2D Sobol' points keyed by depth, and the roulette
//! draws come from a hash of (texel, ray, depth); so results are bit-identical at any thread
//! count. The one-bounce mode computes exactly what it did before bounces existed.
//!
//! Invariant: texel records come out in geometry order with the same surface names and indices
//! as a bundle of the same scene and settings, so `compare` can match them.

use std::f64::consts::PI;

use rayon::prelude::*;

use lightfarm_proto::bounces::BounceCount;
use lightfarm_proto::lights::Light;
use lightfarm_proto::result::{ResultFile, TexelRecord};

use crate::bake::math::sampling::{
    mix64, sample_cosine_hemisphere, sample_uniform_hemisphere, sobol_2d, stream_key, to_world,
    Purpose,
};
use crate::bake::scene::geometry::{Geometry, Primitive};
use crate::bake::tracer::{Hit, Tracer};

/// Paths shorter than this many vertices never meet Russian roulette.
const ROULETTE_FROM_VERTEX: u32 = 3;
/// Largest survival probability of Russian roulette (so every path ends).
const ROULETTE_MAX_SURVIVAL: f64 = 0.95;
/// Paths end here whatever their throughput: `0.95^1000` is far below any f64 weight that
/// matters, so this only guards against a pathological albedo-1 scene.
const MAX_PATH_VERTICES: u32 = 1000;

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

/// What the reference computes and how hard it tries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReferenceSettings {
    /// Paths (cosine-weighted first directions) per texel.
    pub rays: u32,
    /// Bounces of indirect light summed.
    pub bounces: BounceCount,
    /// Seed of every sample stream.
    pub seed: u64,
    /// Only texels whose index within their surface is a multiple of this are computed and
    /// reported (1: every texel); `compare` matches the texels present.
    pub texel_stride: u32,
}

impl ReferenceSettings {
    /// `rays` paths per texel, every texel, `bounces` bounces.
    pub fn new(rays: u32, bounces: BounceCount, seed: u64) -> ReferenceSettings {
        ReferenceSettings {
            rays,
            bounces,
            seed,
            texel_stride: 1,
        }
    }
}

/// Reference direct and indirect radiance for the texels of `g` that `settings` selects,
/// summing `settings.bounces` bounces of indirect light. `progress` counts texels.
pub fn reference(
    g: &Geometry,
    lights: &[Light],
    settings: &ReferenceSettings,
    progress: &(dyn Fn(u64) + Sync),
) -> ResultFile {
    let stride = settings.texel_stride.max(1);
    let selected: Vec<usize> = (0..g.texels.len())
        .filter(|&x| g.texels[x].index % stride == 0)
        .collect();
    reference_at(g, lights, settings, selected, progress)
}

/// [`reference()`] for the texels of `g` listed in `selected` (indices into `g.texels`, in the
/// order the records come out; `settings.texel_stride` is not applied). Each texel's samples
/// depend only on the seed and its index in `g`, so a texel's record is the same whichever
/// others are listed with it.
pub fn reference_at(
    g: &Geometry,
    lights: &[Light],
    settings: &ReferenceSettings,
    selected: Vec<usize>,
    progress: &(dyn Fn(u64) + Sync),
) -> ResultFile {
    let ReferenceSettings {
        rays,
        bounces,
        seed,
        ..
    } = *settings;
    let tracer = Tracer::new(g.primitives.clone(), g.scale());
    let min_r2 = (1e-4 * g.scale()).powi(2);
    let sign = |s: u32| g.surfaces[s as usize].normal_sign;
    let texels: Vec<TexelRecord> = selected
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
            let key = stream_key(seed, Purpose::Reference, x as u64);
            let path_key = stream_key(seed, Purpose::ReferencePath, x as u64);
            let mut sum = [0.0; 3];
            for i in 0..rays {
                let d = to_world(sample_cosine_hemisphere(sobol_2d(key, i)), texel.normal);
                let Some(hit) = tracer.closest(texel.position, d, f64::INFINITY, &sign) else {
                    continue;
                };
                let l = match bounces {
                    BounceCount::Fixed(1) => {
                        let albedo = albedo_of(&tracer, &hit);
                        direct_radiance(&tracer, lights, hit.point, hit.normal, albedo, min_r2)
                    }
                    _ => path_radiance(&tracer, &sign, lights, hit, bounces, path_key, i, min_r2),
                };
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

/// The albedo of the primitive a ray hit.
fn albedo_of(tracer: &Tracer, hit: &Hit) -> [f64; 3] {
    match tracer.primitives()[hit.primitive as usize] {
        Primitive::Rect { albedo, .. } | Primitive::Triangle { albedo, .. } => albedo,
    }
}

/// Radiance arriving along a path's first segment at `first` (the first vertex y₁), summed over
/// up to `bounces` vertices: `Σ_k (Π_{j<k} ρ(y_j)) · L_d(y_k)`, with Russian roulette from
/// vertex [`ROULETTE_FROM_VERTEX`] on. Ray `ray` of the texel whose path stream is `path_key`.
#[allow(clippy::too_many_arguments)]
fn path_radiance(
    tracer: &Tracer,
    sign: &dyn Fn(u32) -> f64,
    lights: &[Light],
    first: Hit,
    bounces: BounceCount,
    path_key: u64,
    ray: u32,
    min_r2: f64,
) -> [f64; 3] {
    let limit = bounces
        .limit()
        .unwrap_or(MAX_PATH_VERTICES)
        .min(MAX_PATH_VERTICES);
    let mut sum = [0.0; 3];
    let mut throughput = [1.0f64; 3];
    let mut hit = first;
    for vertex in 1..=limit {
        let albedo = albedo_of(tracer, &hit);
        let l = direct_radiance(tracer, lights, hit.point, hit.normal, albedo, min_r2);
        for c in 0..3 {
            sum[c] += throughput[c] * l[c];
        }
        if vertex == limit {
            break;
        }
        for c in 0..3 {
            throughput[c] *= albedo[c];
        }
        if vertex + 1 >= ROULETTE_FROM_VERTEX {
            let q = throughput
                .iter()
                .fold(0.0f64, |m, &t| m.max(t))
                .min(ROULETTE_MAX_SURVIVAL);
            let draw = mix64(path_key ^ mix64(((ray as u64) << 20) ^ vertex as u64));
            let u = (draw >> 11) as f64 / (1u64 << 53) as f64;
            if q <= 0.0 || u >= q {
                break;
            }
            throughput = throughput.map(|t| t / q);
        }
        let depth_key = mix64(path_key ^ (vertex as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
        let d = to_world(
            sample_cosine_hemisphere(sobol_2d(depth_key, ray)),
            hit.normal,
        );
        match tracer.closest(hit.point, d, f64::INFINITY, sign) {
            Some(next) => hit = next,
            None => break,
        }
    }
    sum
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
    direct_radiance(
        tracer,
        lights,
        hit.point,
        hit.normal,
        albedo_of(tracer, &hit),
        min_r2,
    )
}

/// Brute-force SH incident radiance (`lightfarm_proto::sh`, world frame) at texel `x` of `g`:
/// `L_lm = (2π/N) Σ Y_lm(ω_i) L_d(hit_i)` over N uniform directions of the texel's geometric
/// hemisphere, with direct light evaluated exactly at every hit (one bounce, as [`reference()`]).
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
    let key = stream_key(seed, Purpose::ReferenceSh, x as u64);
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
    let key = stream_key(seed, Purpose::ReferenceIrradiance, x as u64);
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
    use crate::bake::math::sampling::mixed_key;
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
        let result = reference(
            &g,
            &lights,
            &ReferenceSettings::new(1024, BounceCount::ONE, 3),
            &|_| {},
        );
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

    /// A texel's record depends on the seed and its own index only: listing a few texels, in
    /// any order, gives exactly their records of the whole run.
    #[test]
    fn a_listed_texel_gets_the_record_it_has_in_the_whole_run() {
        let g = closed_box(0.6, 4);
        let lights = [light([0.6, 1.3, 0.9], 1.5)];
        let settings = ReferenceSettings::new(64, BounceCount::All, 7);
        let whole = reference(&g, &lights, &settings, &|_| {});
        let listed = [57, 3, 90, 3];
        let some = reference_at(&g, &lights, &settings, listed.to_vec(), &|_| {});
        assert_eq!(some.texels.len(), listed.len());
        for (record, &x) in some.texels.iter().zip(&listed) {
            assert_eq!(*record, whole.texels[x]);
        }
    }

    #[test]
    fn error_halves_as_rays_quadruple() {
        let g = closed_box(0.7, 2);
        let lights = [light([0.5, 1.5, 0.7], 2.0), light([1.6, 0.4, 1.2], 1.0)];
        let truth = reference(
            &g,
            &lights,
            &ReferenceSettings::new(1 << 16, BounceCount::ONE, 99),
            &|_| {},
        );
        let mut errors = Vec::new();
        for rays in [64u32, 256, 1024] {
            let mut e = 0.0;
            for seed in 0..4 {
                let r = reference(
                    &g,
                    &lights,
                    &ReferenceSettings::new(rays, BounceCount::ONE, seed),
                    &|_| {},
                );
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
        let result = reference(
            &g,
            &lights,
            &ReferenceSettings::new(64, BounceCount::All, 0),
            &|_| {},
        );
        assert!(result.texels.iter().all(|t| t
            .direct
            .iter()
            .chain(&t.indirect)
            .all(|x| x.is_finite())));
    }

    /// Outgoing flux of the indirect light of a closed box: `Σ π L_ind A_texel`.
    fn indirect_flux(g: &Geometry, result: &ResultFile, area: f64) -> f64 {
        let texel_area = area / g.texels.len() as f64;
        result
            .texels
            .iter()
            .map(|t| PI * t.indirect[0] * texel_area)
            .sum()
    }

    /// In a closed box of albedo ρ every reflected photon hits a wall again: the direct light
    /// leaves with flux ρΦ (Φ = 4πI), bounce k with ρ^(k+1)Φ, so all bounces of indirect light
    /// carry ρ²Φ/(1−ρ) and N bounces ρ²Φ(1−ρ^N)/(1−ρ). Albedo 0.9 (paths of ~10 vertices, ten
    /// times the one-bounce light) must still converge to it.
    #[test]
    fn closed_box_all_bounces_match_the_geometric_series() {
        for (rho, rays) in [(0.5, 512u32), (0.9, 512)] {
            let g = closed_box(rho, 6);
            let lights = [light([0.7, 1.3, 0.9], 1.0)];
            let phi = 4.0 * PI;
            let area = 6.0 * 4.0;
            for (bounces, expected) in [
                (BounceCount::All, rho * rho * phi / (1.0 - rho)),
                (
                    BounceCount::Fixed(3),
                    rho * rho * phi * (1.0 - rho.powi(3)) / (1.0 - rho),
                ),
            ] {
                let settings = ReferenceSettings::new(rays, bounces, 5);
                let result = reference(&g, &lights, &settings, &|_| {});
                let flux = indirect_flux(&g, &result, area);
                assert!(
                    (flux - expected).abs() < 0.03 * expected,
                    "albedo {rho}, {bounces} bounces: flux {flux} vs {expected}"
                );
                assert!(result.texels.iter().all(|t| t.indirect[0].is_finite()));
            }
        }
    }

    /// Bit-identical whatever the thread count (every sample is keyed by texel, ray and depth).
    #[test]
    fn all_bounces_are_bit_identical_at_one_and_two_threads() {
        let g = closed_box(0.7, 3);
        let lights = [light([0.5, 1.5, 0.7], 2.0)];
        let settings = ReferenceSettings::new(64, BounceCount::All, 11);
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| reference(&g, &lights, &settings, &|_| {}))
        };
        assert_eq!(run(1), run(2));
    }

    /// Two walls meeting at a corner (floor and the -x wall, everything else open) under a
    /// light: the two-bounce reference minus the one-bounce reference is the second bounce,
    /// computed here independently as the explicit nested integral
    /// `L₂(x) = ρ(x) · mean_i L₁(y_i)`, `L₁(y) = ρ(y) · mean_j L_d(z_j)` (cosine rays at both
    /// levels); all bounces add a little more (light that goes back and forth once more).
    #[test]
    fn second_bounce_matches_the_nested_integral_on_two_walls() {
        let mut g = Geometry::default();
        let aabb = Aabb {
            min: [0.0; 3],
            max: [2.0, 2.0, 2.0],
        };
        g.add_block(
            0,
            "corner",
            &aabb,
            &[Face::NegY, Face::NegX],
            |_| [0.6; 3],
            3,
        );
        let lights = [light([1.3, 1.2, 1.0], 3.0)];
        let one = reference(
            &g,
            &lights,
            &ReferenceSettings::new(4096, BounceCount::ONE, 1),
            &|_| {},
        );
        let two = reference(
            &g,
            &lights,
            &ReferenceSettings::new(4096, BounceCount::Fixed(2), 1),
            &|_| {},
        );
        let all = reference(
            &g,
            &lights,
            &ReferenceSettings::new(4096, BounceCount::All, 1),
            &|_| {},
        );

        let tracer = Tracer::new(g.primitives.clone(), g.scale());
        let min_r2 = (1e-4 * g.scale()).powi(2);
        let sign = |s: u32| g.surfaces[s as usize].normal_sign;
        let (outer, inner) = (512u32, 256u32);
        let (mut num, mut den) = (0.0, 0.0);
        for (x, texel) in g.texels.iter().enumerate() {
            let key = mixed_key(77, 1, x as u64);
            let mut sum = 0.0;
            for i in 0..outer {
                let d = to_world(sample_cosine_hemisphere(sobol_2d(key, i)), texel.normal);
                let Some(y) = tracer.closest(texel.position, d, f64::INFINITY, &sign) else {
                    continue;
                };
                let key_y = mixed_key(78, x as u64, i as u64);
                let mut l1 = 0.0;
                for j in 0..inner {
                    let dz = to_world(sample_cosine_hemisphere(sobol_2d(key_y, j)), y.normal);
                    if let Some(z) = tracer.closest(y.point, dz, f64::INFINITY, &sign) {
                        let albedo = albedo_of(&tracer, &z);
                        l1 +=
                            direct_radiance(&tracer, &lights, z.point, z.normal, albedo, min_r2)[0];
                    }
                }
                sum += albedo_of(&tracer, &y)[0] * l1 / inner as f64;
            }
            let nested = texel.albedo[0] * sum / outer as f64;
            let second = two.texels[x].indirect[0] - one.texels[x].indirect[0];
            num += (second - nested).powi(2);
            den += nested * nested;
            // All bounces carry at least the first two.
            assert!(all.texels[x].indirect[0] >= 0.97 * two.texels[x].indirect[0]);
        }
        let relative_l2 = (num / den).sqrt();
        assert!(den > 0.0);
        assert!(
            relative_l2 < 0.05,
            "second bounce vs nested integral: {relative_l2}"
        );
        // The two walls return little after two bounces: more light escapes than stays.
        let sum = |r: &ResultFile| r.texels.iter().map(|t| t.indirect[0]).sum::<f64>();
        let (s1, s2, sa) = (sum(&one), sum(&two), sum(&all));
        assert!(
            s2 > s1 && sa >= 0.99 * s2 && sa - s2 < s2 - s1,
            "{s1} {s2} {sa}"
        );
    }
}
