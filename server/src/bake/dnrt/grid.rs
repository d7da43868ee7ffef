//! Deferred Neighbouring Radiance Transfer (paper 003 §4–§5.1): the transfer grid of one
//! dynamic object.
//!
//! At every grid point `p` around the object (object frame, metres; grid geometry in
//! `lightfarm_proto::dnrt_grid`) and SH index `j`, with `n_o` the unit vector from `p` to the
//! bounding-sphere centre and `D` the directions from `p` that hit the object:
//! - reflection (eq. 8): `t_j = ∫_D ρ Y_j(n_s) / π² · (ω·n_o)₊ dω`, `n_s` the normal of the
//!   surface point seen in direction `ω` (facing `p`: surfaces are two-sided, as in the
//!   reference solver);
//! - occlusion (eq. 13): `k_j = ∫_D Y_j(ω) / π² · (ω·n_o)₊ dω` (anti-radiance: the irradiance
//!   of a surface facing away from `p` stands in for the radiance the object hides);
//! - stored: `t_j` per RGB channel (`ρ` is the albedo at the hit, per channel: the object's
//!   uniform albedo, or the mesh's own base colour — vertex colours, base-colour texture —
//!   through [`SurfaceAlbedo`]) and `k_j` once, apart (not the paper's `m_j = t_j − k_j`: the
//!   client weighs them with different lighting, see `lightfarm_proto::dnrt_grid`).
//!
//! Both integrals come from one ray pass (one ray serves every `j`, as §5.1.1). Rays: from a
//! point outside the bounding sphere whose cone is narrow, uniform in the cone subtending the
//! sphere (`ClutterGuidedSampler` with α = 1: every ray that can hit is in the cone); otherwise
//! cosine-weighted over the hemisphere of `n_o`. Each ray carries the weight
//! `(cosθ/π) / pdf`, so `∫ f cos dω = π · mean(weight · f)`.
//!
//! Appendix A ([`DnrtNormals::Convolution`]): instead of integrating about `n_o`, the transfer
//! functions `ρ Y_j(n_s)/π²` and `Y_j(ω)/π²` on `D` are projected onto SH over directions and
//! convolved with the clamped cosine: `Â_t ∫_D f_j Y_t dω`, so a receiver of any normal n gets
//! `ρ Σ_t (Σ_j c_j T_jt − π Σ_j l_j K_jt) Y_t(n)` (order-2 band limit of the cosine lobe).
//!
//! Invariants: every random number is a pure function of (seed, purpose, grid point, ray
//! index); points run in parallel with rayon but each depends only on its own stream, so a
//! grid is bit-identical at any thread count. f64 throughout; the grid is quantised last.

use rayon::prelude::*;

use glam::DVec3;
use lightfarm_proto::dnrt_grid::{
    fitted_term_ranges, placement_offset, DnrtGrid, DnrtNormals, SLOTS,
};
use lightfarm_proto::scene::DnrtSettings;
use lightfarm_proto::sh::{irradiance_weights, sh_basis};

use crate::bake::drt::clutter_sampling::{ClutterGuidedSampler, Sphere};
use crate::bake::math::sampling::{sobol_2d, stream_key, Purpose};
use crate::bake::scene::geometry::Primitive;
use crate::bake::scene::mesh_albedo::SurfaceAlbedo;
use crate::bake::sh::probe_volume::sample_uniform_sphere;
use crate::bake::tracer::Tracer;

/// A bounding sphere (object frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoundingSphere {
    pub centre: [f64; 3],
    pub radius: f64,
}

/// The sphere around the axis-aligned bounding box's centre through the farthest vertex
/// (not the smallest sphere, but it bounds every triangle, which is what the sampler needs).
pub fn bounding_sphere(triangles: &[[[f64; 3]; 3]]) -> BoundingSphere {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for v in triangles.iter().flatten() {
        for k in 0..3 {
            lo[k] = lo[k].min(v[k]);
            hi[k] = hi[k].max(v[k]);
        }
    }
    let centre: [f64; 3] = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let radius = triangles
        .iter()
        .flatten()
        .map(|v| DVec3::from(*v).distance(DVec3::from(centre)))
        .fold(0.0, f64::max);
    BoundingSphere { centre, radius }
}

/// Reflection and occlusion coefficients of every grid point.
#[derive(Clone, Debug, PartialEq)]
pub struct TransferCoefficients {
    pub n_sh: usize,
    /// `(point · 3 + channel) · n_sh + j`: `t_j` (eq. 8, with the albedo at each hit).
    pub reflection: Vec<f64>,
    /// `point · n_sh + j`: `k_j` (eq. 13).
    pub occlusion: Vec<f64>,
}

/// Rays toward the object alone: its bounding sphere, padded by the tracer's epsilon (and a
/// relative 1e-6) so no surface point lies outside it, sampled with `alpha` 1.
fn object_sampler(tracer: &Tracer, sphere: BoundingSphere) -> ClutterGuidedSampler {
    ClutterGuidedSampler {
        spheres: vec![Sphere {
            center: sphere.centre,
            radius: sphere.radius * (1.0 + 1e-6) + tracer.epsilon,
        }],
        alpha: 1.0,
    }
}

/// The reflection and occlusion coefficients at arbitrary points `points` (object frame),
/// `rays` Monte Carlo rays each; `albedo` gives the object's albedo at each hit (triangle
/// index = primitive index of `tracer`).
pub fn transfer_at_points(
    tracer: &Tracer,
    sphere: BoundingSphere,
    points: &[[f64; 3]],
    n_sh: usize,
    rays: u32,
    seed: u64,
    albedo: SurfaceAlbedo,
) -> TransferCoefficients {
    let sampler = object_sampler(tracer, sphere);
    let per_point: Vec<(Vec<f64>, Vec<f64>)> = points
        .par_iter()
        .enumerate()
        .map(|(p, x)| {
            let to_centre = DVec3::from(sphere.centre) - DVec3::from(*x);
            let dist = to_centre.length();
            let n_o = if dist > 1e-12 * sphere.radius.max(1e-12) {
                (to_centre / dist).to_array()
            } else {
                [0.0, 1.0, 0.0]
            };
            let key = stream_key(seed, Purpose::Dnrt, p as u64);
            let mut reflection = vec![0.0; 3 * n_sh];
            let mut occlusion = vec![0.0; n_sh];
            for i in 0..rays {
                let u_pick = (i as f64 + 0.5) / rays as f64;
                let (w, weight) = sampler.sample(*x, n_o, u_pick, sobol_2d(key, i));
                if weight <= 0.0 {
                    continue;
                }
                let Some(hit) = tracer.closest(*x, w, f64::INFINITY, &|_| 1.0) else {
                    continue;
                };
                let rho = albedo_at(tracer, &albedo, &hit);
                let y_surface = sh_basis(hit.normal);
                let y_direction = sh_basis(w);
                for j in 0..n_sh {
                    for c in 0..3 {
                        reflection[c * n_sh + j] += weight * rho[c] * y_surface[j];
                    }
                    occlusion[j] += weight * y_direction[j];
                }
            }
            // ∫ f cos dω / π² = π · mean(weight · f) / π².
            let scale = 1.0 / (std::f64::consts::PI * rays as f64);
            (
                reflection.into_iter().map(|v| v * scale).collect(),
                occlusion.into_iter().map(|v| v * scale).collect(),
            )
        })
        .collect();
    concatenate_points(n_sh, per_point)
}

/// Appendix A: per point, SH index j (irradiance) and t (direction),
/// `R_jt = ∫_D ρ Y_j(n_s) Y_t(ω) / π² dω` per channel (layout
/// `(point · 3 + channel) · n_sh² + j · n_sh + t`) and `O_jt = ∫_D Y_j(ω) Y_t(ω) / π² dω`
/// (layout `point · n_sh² + j · n_sh + t`) over all directions that hit the object (no cosine:
/// the receiver's clamped cosine is applied at runtime by convolution). Rays: uniform in the
/// bounding sphere's cone where it is narrow, else uniform over the whole sphere (near the
/// object it can cover more than a hemisphere).
pub fn convolved_transfer_at_points(
    tracer: &Tracer,
    sphere: BoundingSphere,
    points: &[[f64; 3]],
    n_sh: usize,
    rays: u32,
    seed: u64,
    albedo: SurfaceAlbedo,
) -> TransferCoefficients {
    let pi = std::f64::consts::PI;
    let sampler = object_sampler(tracer, sphere);
    let radius = sampler.spheres[0].radius;
    let nn = n_sh * n_sh;
    let per_point: Vec<(Vec<f64>, Vec<f64>)> = points
        .par_iter()
        .enumerate()
        .map(|(p, x)| {
            let to_centre = DVec3::from(sphere.centre) - DVec3::from(*x);
            let dist = to_centre.length();
            // Narrow cone (the sampler's own criterion): sample it; otherwise the sphere.
            let cone = dist > radius && radius / dist < (1.0f64 - 0.81).sqrt();
            let n_o = if dist > 0.0 {
                (to_centre / dist).to_array()
            } else {
                [0.0, 1.0, 0.0]
            };
            let key = stream_key(seed, Purpose::DnrtConvolved, p as u64);
            let mut reflection = vec![0.0; 3 * nn];
            let mut occlusion = vec![0.0; nn];
            for i in 0..rays {
                let u = sobol_2d(key, i);
                // 1 / pdf of the direction.
                let (w, inv_pdf) = if cone {
                    let (w, weight) = sampler.sample(*x, n_o, (i as f64 + 0.5) / rays as f64, u);
                    let cos = DVec3::from(w).dot(DVec3::from(n_o));
                    if weight <= 0.0 || cos <= 0.0 {
                        continue;
                    }
                    (w, weight * pi / cos)
                } else {
                    (sample_uniform_sphere(u), 4.0 * pi)
                };
                let Some(hit) = tracer.closest(*x, w, f64::INFINITY, &|_| 1.0) else {
                    continue;
                };
                let rho = albedo_at(tracer, &albedo, &hit);
                let y_surface = sh_basis(hit.normal);
                let y_direction = sh_basis(w);
                for j in 0..n_sh {
                    for t in 0..n_sh {
                        let r = inv_pdf * y_surface[j] * y_direction[t];
                        for c in 0..3 {
                            reflection[c * nn + j * n_sh + t] += rho[c] * r;
                        }
                        occlusion[j * n_sh + t] += inv_pdf * y_direction[j] * y_direction[t];
                    }
                }
            }
            let scale = 1.0 / (pi * pi * rays as f64);
            (
                reflection.into_iter().map(|v| v * scale).collect(),
                occlusion.into_iter().map(|v| v * scale).collect(),
            )
        })
        .collect();
    concatenate_points(n_sh, per_point)
}

/// The object's albedo where `hit` landed.
fn albedo_at(tracer: &Tracer, albedo: &SurfaceAlbedo, hit: &crate::bake::tracer::Hit) -> [f64; 3] {
    match (albedo, &tracer.primitives()[hit.primitive as usize]) {
        (SurfaceAlbedo::Uniform(a), _) => *a,
        (_, Primitive::Triangle { v, .. }) => albedo.at(hit.primitive as usize, v, hit.point),
        (_, Primitive::Rect { albedo, .. }) => *albedo,
    }
}

/// Per-point (reflection, occlusion) coefficient runs, concatenated in point order.
fn concatenate_points(n_sh: usize, per_point: Vec<(Vec<f64>, Vec<f64>)>) -> TransferCoefficients {
    let (reflection, occlusion) =
        per_point
            .into_iter()
            .fold((Vec::new(), Vec::new()), |(mut r, mut o), (t, k)| {
                r.extend(t);
                o.extend(k);
                (r, o)
            });
    TransferCoefficients {
        n_sh,
        reflection,
        occlusion,
    }
}

/// A tracer over an object's triangles alone.
pub fn object_tracer(triangles: &[[[f64; 3]; 3]]) -> Tracer {
    let primitives: Vec<Primitive> = triangles
        .iter()
        .map(|v| Primitive::Triangle {
            v: *v,
            albedo: [0.0; 3],
            lightmap: None,
        })
        .collect();
    let scale = triangles
        .iter()
        .flatten()
        .flatten()
        .fold(1e-3f64, |m, x| m.max(x.abs()));
    Tracer::new(primitives, scale)
}

/// The unquantised `t_j`, `k_j` of a whole grid (layout of `lightfarm_proto::dnrt_grid`) and
/// the grid's geometry.
pub struct DnrtValues {
    pub sphere: BoundingSphere,
    pub inner_half_extent: f64,
    pub outer_half_extent: f64,
    pub values: Vec<f64>,
}

/// Grid point positions (object frame) in grid order.
pub fn grid_points(settings: &DnrtSettings, sphere: BoundingSphere) -> Vec<[f64; 3]> {
    let n = settings.resolution as usize;
    let e = settings.extent * sphere.radius;
    let offsets: Vec<f64> = (0..n)
        .map(|i| placement_offset(settings.placement, e, n, i))
        .collect();
    let mut points = Vec::with_capacity(n * n * n);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                points.push([
                    sphere.centre[0] + offsets[i],
                    sphere.centre[1] + offsets[j],
                    sphere.centre[2] + offsets[k],
                ]);
            }
        }
    }
    points
}

/// Bakes `t_j` per channel and `k_j` for every grid point, unquantised (layout of
/// `lightfarm_proto::dnrt_grid`).
pub fn dnrt_values(
    triangles: &[[[f64; 3]; 3]],
    albedo: SurfaceAlbedo,
    settings: &DnrtSettings,
    seed: u64,
) -> DnrtValues {
    let sphere = bounding_sphere(triangles);
    let tracer = object_tracer(triangles);
    let points = grid_points(settings, sphere);
    let n_sh = settings.sh as usize;
    let (coeffs, terms, weight): (_, usize, Vec<f64>) = match settings.normals {
        DnrtNormals::Intermediate => (
            transfer_at_points(&tracer, sphere, &points, n_sh, settings.rays, seed, albedo),
            n_sh,
            vec![1.0; n_sh],
        ),
        // G_jt = Â_t (R_jt − O_jt): the clamped-cosine convolution (Funk–Hecke).
        DnrtNormals::Convolution => {
            let a = irradiance_weights();
            (
                convolved_transfer_at_points(
                    &tracer,
                    sphere,
                    &points,
                    n_sh,
                    settings.rays,
                    seed,
                    albedo,
                ),
                n_sh * n_sh,
                (0..n_sh * n_sh).map(|k| a[k % n_sh]).collect(),
            )
        }
    };
    let mut values = Vec::with_capacity(points.len() * SLOTS * terms);
    for p in 0..points.len() {
        for c in 0..3 {
            let at = (p * 3 + c) * terms;
            let t = &coeffs.reflection[at..at + terms];
            values.extend(weight.iter().zip(t).map(|(w, t)| w * t));
        }
        let o = &coeffs.occlusion[p * terms..(p + 1) * terms];
        values.extend(weight.iter().zip(o).map(|(w, o)| w * o));
    }
    DnrtValues {
        sphere,
        inner_half_extent: settings.extent * sphere.radius,
        outer_half_extent: settings.outer_extent * sphere.radius,
        values,
    }
}

/// Quantises baked values into the grid the bundle carries (codec and placement from
/// `settings`; u8 ranges fitted to the data, within the analytic bounds).
pub fn encode_grid(object: &str, baked: &DnrtValues, settings: &DnrtSettings) -> DnrtGrid {
    let n_sh = settings.sh as usize;
    DnrtGrid::encode_values(
        object,
        baked.sphere.centre.map(|x| x as f32),
        baked.sphere.radius as f32,
        baked.inner_half_extent as f32,
        baked.outer_half_extent as f32,
        settings.resolution,
        settings.sh,
        settings.placement,
        settings.normals,
        settings.codec,
        fitted_term_ranges(&baked.values, n_sh, settings.normals),
        &baked.values,
    )
}

/// Bakes and encodes the grid of one object.
pub fn bake_dnrt_grid(
    object: &str,
    triangles: &[[[f64; 3]; 3]],
    albedo: SurfaceAlbedo,
    settings: &DnrtSettings,
    seed: u64,
) -> DnrtGrid {
    let baked = dnrt_values(triangles, albedo, settings, seed);
    encode_grid(object, &baked, settings)
}

/// A closed icosphere (outward-wound), `subdivisions` times subdivided, radius `r` at `c`.
pub fn icosphere(c: [f64; 3], r: f64, subdivisions: u32) -> Vec<[[f64; 3]; 3]> {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let verts = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ];
    let faces = [
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    let unit = |v: [f64; 3]| {
        let v = DVec3::from(v);
        (v / v.length()).to_array()
    };
    let mut tris: Vec<[[f64; 3]; 3]> = faces
        .iter()
        .map(|f| [unit(verts[f[0]]), unit(verts[f[1]]), unit(verts[f[2]])])
        .collect();
    for _ in 0..subdivisions {
        let mid = |a: [f64; 3], b: [f64; 3]| unit([a[0] + b[0], a[1] + b[1], a[2] + b[2]]);
        tris = tris
            .iter()
            .flat_map(|[a, b, c]| {
                let (ab, bc, ca) = (mid(*a, *b), mid(*b, *c), mid(*c, *a));
                [[*a, ab, ca], [ab, *b, bc], [ca, bc, *c], [ab, bc, ca]]
            })
            .collect();
    }
    tris.iter()
        .map(|tri| tri.map(|v| [c[0] + r * v[0], c[1] + r * v[1], c[2] + r * v[2]]))
        .collect()
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    const Y0: f64 = 0.282_094_791_773_878_1;
    const Y1: f64 = 0.488_602_511_902_919_9;

    /// ∫_cone (n_s·a) cosθ dω over the directions from a point at distance `s` radii that hit a
    /// sphere, `a` the unit axis towards the centre. Closed form: the ray at angle θ hits the
    /// sphere where `n_s·a = −(s sin²θ + cosθ √(1 − s² sin²θ))`; with `x = s cosθ` the
    /// integral reduces to `∫ x² √(x² − (s² − 1)) dx`, which is elementary.
    fn sphere_band1_integral(s: f64) -> f64 {
        let inner =
            s * (s * s + 1.0) / 8.0 - (s * s - 1.0).powi(2) / 16.0 * ((s + 1.0) / (s - 1.0)).ln();
        -2.0 * PI * (1.0 / (4.0 * s.powi(3)) + inner / s.powi(3))
    }

    /// Reflection and occlusion of a sphere of uniform albedo have closed forms in bands 0 and
    /// 1: `t_0/ρ = k_0 = Y_0 sin²α / π`; `t_1m/ρ = Y_1 (a·e_m) I₁(s) / π²`;
    /// `k_1m = Y_1 (a·e_m) · 2π(1 − cos³α)/3 / π²`, with `sin α = 1/s`.
    #[test]
    fn sphere_coefficients_match_closed_forms_in_bands_0_and_1() {
        let r = 0.5;
        let centre = [0.2, -0.1, 0.3];
        let tris = icosphere(centre, r, 5);
        let tracer = object_tracer(&tris);
        let sphere = bounding_sphere(&tris);
        // Points at 1.5, 2.5 and 6 radii along varied directions.
        let dirs = [[1.0, 0.0, 0.0], [0.0, -0.6, 0.8], [0.48, 0.6, -0.64]];
        let mut points = Vec::new();
        let mut expected = Vec::new();
        for (s, d) in [1.5, 2.5, 6.0].iter().zip(dirs) {
            points.push([0, 1, 2].map(|k| centre[k] + s * r * d[k]));
            let a = d.map(|x| -x); // towards the centre
            let sin2 = 1.0 / (s * s);
            let cos3 = (1.0 - sin2).sqrt().powi(3);
            // Sloan band-1 order: y, z, x.
            let axis = [a[1], a[2], a[0]];
            let i1 = sphere_band1_integral(*s);
            let t: Vec<f64> = std::iter::once(Y0 * sin2 / PI)
                .chain(axis.iter().map(|c| Y1 * c * i1 / (PI * PI)))
                .collect();
            let k: Vec<f64> = std::iter::once(Y0 * sin2 / PI)
                .chain(
                    axis.iter()
                        .map(|c| Y1 * c * 2.0 * PI * (1.0 - cos3) / 3.0 / (PI * PI)),
                )
                .collect();
            expected.push((t, k));
        }
        let got = transfer_at_points(
            &tracer,
            sphere,
            &points,
            4,
            1 << 14,
            7,
            SurfaceAlbedo::Uniform([1.0; 3]),
        );
        for (p, (t, k)) in expected.iter().enumerate() {
            let scale = t[0].abs();
            for j in 0..4 {
                let (gt, gk) = (got.reflection[p * 12 + j], got.occlusion[p * 4 + j]);
                assert!(
                    (gt - t[j]).abs() < 0.01 * scale,
                    "point {p} t_{j}: {gt} vs {}",
                    t[j]
                );
                assert!(
                    (gk - k[j]).abs() < 0.01 * scale,
                    "point {p} k_{j}: {gk} vs {}",
                    k[j]
                );
            }
        }
    }

    /// Far from a small object, `k_j → Y_j(n_o) · sin²α / π` for every j (a point occluder
    /// of cosine-weighted solid angle π sin²α).
    #[test]
    fn occlusion_of_a_distant_small_object_is_its_solid_angle_times_the_basis() {
        let tris = icosphere([0.0; 3], 0.05, 3);
        let tracer = object_tracer(&tris);
        let sphere = bounding_sphere(&tris);
        let p = [1.2, 2.0, -1.6];
        let dist = DVec3::from(p).length();
        let n_o = p.map(|x| -x / dist);
        let got = transfer_at_points(
            &tracer,
            sphere,
            &[p],
            9,
            4096,
            3,
            SurfaceAlbedo::Uniform([1.0; 3]),
        );
        let sin2 = (0.05 / dist).powi(2);
        let y = sh_basis(n_o);
        let k0 = Y0 * sin2 / PI;
        for j in 0..9 {
            let want = y[j] * sin2 / PI;
            assert!(
                (got.occlusion[j] - want).abs() < 0.01 * k0,
                "k_{j}: {} vs {want}",
                got.occlusion[j]
            );
        }
        // And m_0 = (ρ − 1) k_0 ≤ 0 as the analytic range says.
        let m0 = 0.5 * got.reflection[0] - got.occlusion[0];
        assert!(m0 < 0.0 && (m0 + 0.5 * k0).abs() < 0.01 * k0, "{m0}");
    }

    #[test]
    fn a_grid_is_bit_identical_at_one_and_two_threads_and_within_analytic_ranges() {
        let tris = icosphere([0.0, 0.4, 0.0], 0.4, 2);
        let settings = DnrtSettings {
            resolution: 6,
            rays: 64,
            ..DnrtSettings::default()
        };
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    dnrt_values(&tris, SurfaceAlbedo::Uniform([0.8, 0.2, 0.1]), &settings, 5).values
                })
        };
        let one = run(1);
        let two = run(2);
        assert_eq!(
            one.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            two.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
        );
        for (k, v) in one.iter().enumerate() {
            let [lo, hi] = lightfarm_proto::dnrt_grid::analytic_range(k % 9);
            assert!(
                v.is_finite() && *v >= lo - 1e-12 && *v <= hi + 1e-12,
                "{k}: {v}"
            );
        }
    }

    /// Appendix A's direction projection of the occlusion has closed forms for a sphere:
    /// `O_00 = Y_0² Ω / π²` with `Ω = 2π(1 − cos α)`, and `O_0t = Y_0 Y_1 (a·e_t) π sin²α / π²`
    /// for band 1; checked near (whole-sphere sampling) and far (cone sampling).
    #[test]
    fn convolved_occlusion_matches_closed_forms_near_and_far() {
        let r = 0.5;
        let tris = icosphere([0.0; 3], r, 5);
        let tracer = object_tracer(&tris);
        let sphere = bounding_sphere(&tris);
        for (s, d) in [(1.5, [0.0, 0.6, 0.8]), (5.0, [-0.48, 0.6, 0.64])] {
            let p = d.map(|x| s * r * x);
            let a = d.map(|x: f64| -x);
            let sin2 = 1.0 / (s * s);
            let cos = (1.0 - sin2).sqrt();
            let got = convolved_transfer_at_points(
                &tracer,
                sphere,
                &[p],
                4,
                1 << 15,
                11,
                SurfaceAlbedo::Uniform([1.0; 3]),
            );
            let o00 = Y0 * Y0 * 2.0 * PI * (1.0 - cos) / (PI * PI);
            let axis = [a[1], a[2], a[0]];
            assert!(
                (got.occlusion[0] - o00).abs() < 0.01 * o00,
                "s = {s}: O_00 {} vs {o00}",
                got.occlusion[0]
            );
            for t in 1..4 {
                let want = Y0 * Y1 * axis[t - 1] * PI * sin2 / (PI * PI);
                assert!(
                    (got.occlusion[t] - want).abs() < 0.01 * o00,
                    "s = {s}: O_0{t} {} vs {want}",
                    got.occlusion[t]
                );
            }
            // Symmetry of the occlusion in (j, t).
            for j in 0..4 {
                for t in 0..4 {
                    let (x, y) = (got.occlusion[j * 4 + t], got.occlusion[t * 4 + j]);
                    assert!((x - y).abs() < 1e-12, "{j} {t}");
                }
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod albedo_tests {
    use super::*;
    use crate::bake::scene::mesh::load_mesh;
    use lightfarm_proto::scene::Transform;
    use std::f64::consts::PI;

    /// Writes `tris` (non-indexed) with one COLOR_0 per vertex as `name.gltf` + `name.bin`.
    fn write_gltf(
        dir: &std::path::Path,
        name: &str,
        tris: &[[[f64; 3]; 3]],
        colour: &dyn Fn(&[[f64; 3]; 3]) -> [f32; 3],
    ) {
        let mut bin = Vec::new();
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for t in tris {
            for v in t {
                for k in 0..3 {
                    let x = v[k] as f32;
                    lo[k] = lo[k].min(x);
                    hi[k] = hi[k].max(x);
                    bin.extend_from_slice(&x.to_le_bytes());
                }
            }
        }
        let pos_len = bin.len();
        for t in tris {
            let c = colour(t);
            for _ in 0..3 {
                for x in c {
                    bin.extend_from_slice(&x.to_le_bytes());
                }
            }
        }
        let n = tris.len() * 3;
        let json = format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"COLOR_0":1}}}}]}}],
"buffers":[{{"uri":"{name}.bin","byteLength":{total}}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":{pos_len}}},{{"buffer":0,"byteOffset":{pos_len},"byteLength":{col_len}}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":{n},"type":"VEC3","min":[{},{},{}],"max":[{},{},{}]}},
{{"bufferView":1,"componentType":5126,"count":{n},"type":"VEC3"}}]}}"#,
            lo[0],
            lo[1],
            lo[2],
            hi[0],
            hi[1],
            hi[2],
            total = bin.len(),
            col_len = bin.len() - pos_len,
        );
        std::fs::write(dir.join(format!("{name}.bin")), &bin).unwrap();
        std::fs::write(dir.join(format!("{name}.gltf")), json).unwrap();
    }

    fn temp_dir(tag: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("lf-dnrt-albedo-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// Uniform vertex colours give the grid of the same uniform albedo.
    #[test]
    fn uniform_vertex_colours_bake_the_uniform_albedo_grid() {
        let dir = temp_dir("uniform");
        let tris = icosphere([0.0, 0.1, 0.0], 0.4, 2);
        write_gltf(&dir, "ball", &tris, &|_| [0.75, 0.125, 0.0625]);
        let mesh = load_mesh("dynamic \"ball\"", &dir, "ball.gltf", &Transform::default()).unwrap();
        assert_eq!(mesh.albedo.triangles.len(), mesh.triangles.len());
        assert!(!mesh.albedo.is_empty());
        let settings = DnrtSettings {
            resolution: 5,
            rays: 64,
            ..DnrtSettings::default()
        };
        let coloured = dnrt_values(
            &mesh.triangles,
            SurfaceAlbedo::Mesh {
                albedo: &mesh.albedo,
                fallback: [0.3; 3],
            },
            &settings,
            9,
        );
        let uniform = dnrt_values(
            &mesh.triangles,
            SurfaceAlbedo::Uniform([0.75, 0.125, 0.0625]),
            &settings,
            9,
        );
        let scale = uniform.values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (k, (a, b)) in coloured.values.iter().zip(&uniform.values).enumerate() {
            assert!((a - b).abs() <= 1e-12 * scale, "{k}: {a} vs {b}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A ball red on +x and green on −x: seen from +x (where only the red half is visible),
    /// `t_0` is the red albedo times the closed form in red and the green one in green, and
    /// the other way round from −x.
    #[test]
    fn a_half_red_half_green_ball_gives_channel_dependent_coefficients() {
        let dir = temp_dir("halves");
        let r = 0.4;
        let tris = icosphere([0.0; 3], r, 4);
        let (red, green) = ([0.875f32, 0.125, 0.0625], [0.125f32, 0.875, 0.0625]);
        write_gltf(&dir, "ball", &tris, &|t| {
            if t[0][0] + t[1][0] + t[2][0] > 0.0 {
                red
            } else {
                green
            }
        });
        let mesh = load_mesh("dynamic \"ball\"", &dir, "ball.gltf", &Transform::default()).unwrap();
        let tracer = object_tracer(&mesh.triangles);
        let sphere = bounding_sphere(&mesh.triangles);
        let s = 2.5;
        let points = [[s * r, 0.0, 0.0], [-s * r, 0.0, 0.0]];
        let got = transfer_at_points(
            &tracer,
            sphere,
            &points,
            4,
            1 << 13,
            4,
            SurfaceAlbedo::Mesh {
                albedo: &mesh.albedo,
                fallback: [0.5; 3],
            },
        );
        // Closed form of t_0/ρ for a sphere: Y_0 sin²α / π.
        let t0 = 0.282_094_791_773_878_1 / (s * s) / PI;
        for (p, colour) in [(0usize, red), (1, green)] {
            for c in 0..3 {
                let want = colour[c] as f64 * t0;
                let t = got.reflection[(p * 3 + c) * 4];
                assert!(
                    (t - want).abs() < 0.02 * t0,
                    "point {p} channel {c}: {t} vs {want}"
                );
                // Occlusion wins: m_0 < 0 in every channel.
                assert!(t - got.occlusion[p * 4] < 0.0);
            }
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
