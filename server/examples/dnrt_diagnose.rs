//! Splits the error of DNRT against the brute-force reference into its terms, on the texels
//! near a posed dynamic object (diagnostic for the DNRT accuracy figures).
//!
//! `cargo run --release -p lightfarm-server --example dnrt_diagnose -- SCENE.json LIGHTS.json [BUNDLE.lfb] [RAYS]`
//!
//! On the texels within two bounding radii of the first pose, with the reference's own
//! machinery (one bounce, two-sided surfaces, shadow rays at every hit) and the same
//! cosine rays for every term, the reference delta (with object − without) is split into
//! - occlusion: the direct radiance of what the object hides (scene without the object),
//! - reflection: the object's own direct radiance where the rays hit it,
//! - shadow: the change of the direct radiance at the other hits (the object's shadow),
//!
//! and compared with DNRT's model evaluated without any grid, at the texel itself:
//! - `exact-n`: the receiver's own cosine, `E(n_s)` and `E(ω)` from the SH `c_j`,
//! - `n_o`: the intermediate normal, `ρ (n_o·n)₊ Σ c_j (ρ_o t_j − k_j)` (the baked quantity),
//!
//! each with `c_j` split by what the reference lets the object reflect and hide (reflection:
//! the point lights' direct lobe; occlusion: the scene's radiance without point lights) or
//! the same `c_j` for both (what a light probe holds). The irradiance SH at the object's
//! centre is computed by brute force (uniform rays on the scene without the object) and,
//! when a bundle is given, compared with what `eval` samples from its probe volume.

#![allow(clippy::needless_range_loop)]

use std::f64::consts::PI;
use std::path::Path;

use lightfarm_proto::lights::LightSet;
use lightfarm_proto::scene::Transform;
use lightfarm_proto::sh::{irradiance_weights, sh_basis};
use lightfarm_server::bake::dnrt::grid::{bounding_sphere, object_tracer, transfer_at_points};
use lightfarm_server::bake::math::sampling::{
    mixed_key, sample_cosine_hemisphere, sobol_2d, to_world,
};
use lightfarm_server::bake::reference::direct_radiance;
use lightfarm_server::bake::scene::geometry::{Geometry, Primitive};
use lightfarm_server::bake::scene::mesh::load_mesh;
use lightfarm_server::bake::scene::mesh_albedo::SurfaceAlbedo;
use lightfarm_server::bake::sh::probe_volume::sample_uniform_sphere;
use lightfarm_server::bake::tracer::Tracer;

type Rgb = [f64; 3];
/// SH coefficients per channel.
type Sh = [[f64; 9]; 3];

fn albedo_of(t: &Tracer, prim: u32) -> Rgb {
    match t.primitives()[prim as usize] {
        Primitive::Rect { albedo, .. } | Primitive::Triangle { albedo, .. } => albedo,
    }
}

fn rel(pairs: &[(Rgb, Rgb)]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (a, b) in pairs {
        for c in 0..3 {
            num += (a[c] - b[c]).powi(2);
            den += b[c].powi(2);
        }
    }
    (num / den).sqrt()
}

fn norm(v: &[Rgb]) -> f64 {
    v.iter().flatten().map(|x| x * x).sum::<f64>().sqrt()
}

fn add(a: Rgb, b: Rgb) -> Rgb {
    [0, 1, 2].map(|c| a[c] + b[c])
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let scene_path = Path::new(&args[1]);
    let lights = LightSet::from_json(&std::fs::read_to_string(&args[2])?)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let bundle_path = args.get(3).filter(|s| s.ends_with(".lfb"));
    let rays: u32 = args
        .iter()
        .skip(3)
        .find_map(|s| s.parse().ok())
        .unwrap_or(8192);
    let (scene, dir) = lightfarm_server::cli::bake::load_scene(scene_path)?;
    let g0 = Geometry::from_scene(&scene, &dir)?;
    let mut g1 = Geometry::from_scene(&scene, &dir)?;
    g1.add_posed_dynamic(&scene, &dir, &lights.poses)?;
    let pose = &lights.poses[0];
    let object = scene.dynamic.iter().find(|d| d.id == pose.id).unwrap();
    let posed = load_mesh(
        &object.id,
        &dir,
        &object.mesh,
        &Transform {
            translation: pose.translation,
            rotation: pose.rotation,
            scale: [1.0; 3],
        },
    )?
    .triangles;
    let rho_o = object.albedo;
    let sphere = bounding_sphere(&posed);
    let centre = sphere.centre;
    let radius = sphere.radius;
    let n_static = g0.primitives.len() as u32;
    let t0 = Tracer::new(g0.primitives.clone(), g0.scale());
    let t1 = Tracer::new(g1.primitives.clone(), g1.scale());
    let ball = object_tracer(&posed);
    let min_r2 = (1e-4 * g0.scale()).powi(2);
    let sign = |s: u32| g0.surfaces[s as usize].normal_sign;
    let ls = &lights.lights;

    // Irradiance SH at the centre: point lights' direct lobe, and the scene's radiance
    // (direct radiance of the surfaces, scene without the object) by brute force.
    let a = irradiance_weights();
    let mut c_dir = [[0.0f64; 9]; 3];
    for l in ls {
        if t0.occluded(centre, l.position) {
            continue;
        }
        let d: [f64; 3] = std::array::from_fn(|k| l.position[k] - centre[k]);
        let r2: f64 = d.iter().map(|x| x * x).sum();
        let y = sh_basis(d.map(|x| x / r2.sqrt()));
        for ch in 0..3 {
            for k in 0..9 {
                c_dir[ch][k] += a[k] * l.intensity[ch] / r2 * y[k];
            }
        }
    }
    let n_env = 1u32 << 16;
    let key = mixed_key(1, 901, 0);
    let mut c_env = [[0.0f64; 9]; 3];
    for i in 0..n_env {
        let w = sample_uniform_sphere(sobol_2d(key, i));
        let Some(hit) = t0.closest(centre, w, f64::INFINITY, &sign) else {
            continue;
        };
        let l = direct_radiance(
            &t0,
            ls,
            hit.point,
            hit.normal,
            albedo_of(&t0, hit.primitive),
            min_r2,
        );
        let y = sh_basis(w);
        for ch in 0..3 {
            for k in 0..9 {
                c_env[ch][k] += a[k] * 4.0 * PI / n_env as f64 * l[ch] * y[k];
            }
        }
    }
    println!(
        "object {:?}: centre {centre:?}, radius {radius:.4}",
        object.id
    );
    println!(
        "c_dir (green) {:?}",
        c_dir[1].map(|x| (x * 1e4).round() / 1e4)
    );
    println!(
        "c_env (green) {:?}",
        c_env[1].map(|x| (x * 1e4).round() / 1e4)
    );
    let c_sum: [[f64; 9]; 3] =
        std::array::from_fn(|ch| std::array::from_fn(|k| c_dir[ch][k] + c_env[ch][k]));

    // What eval gives the object (probe volume + direct lobe), when a bundle is given.
    if let Some(path) = bundle_path {
        use lightfarm_client::*;
        let bundle = decode(&std::fs::read(path)?)?;
        let occluders = Occluders::from_layout(&bundle.layout);
        let averaged = direct_from_point_lights_averaged(&bundle.layout, &occluders, ls, 4);
        let mut runtime = Runtime::try_new(bundle)?;
        let mut field = ProbeField::default();
        runtime.apply_probes(&averaged, &mut field)?;
        let volume = runtime.bundle().probes.as_ref().unwrap();
        let cf = centre.map(|x| x as f32);
        let probe = irradiance_sh_at(volume, &field, cf);
        let lobe = point_light_irradiance_sh(&occluders, ls, cf);
        println!(
            "eval probe (green) {:?}",
            probe[1].map(|x| (x * 1e4).round() / 1e4)
        );
        println!(
            "eval lobe  (green) {:?}",
            lobe[1].map(|x| (x * 1e4).round() / 1e4)
        );
        let d: f64 = (0..9)
            .map(|k| (probe[1][k] as f64 - c_env[1][k]).powi(2))
            .sum::<f64>()
            .sqrt();
        let n: f64 = c_env[1].iter().map(|x| x * x).sum::<f64>().sqrt();
        println!(
            "probe vs brute-force scene irradiance SH: relative L2 {:.4}",
            d / n
        );
    }

    // Texels near the object.
    let near: Vec<usize> = (0..g0.texels.len())
        .filter(|&x| {
            let p = g0.texels[x].position;
            (0..3)
                .map(|k| (p[k] - centre[k]).powi(2))
                .sum::<f64>()
                .sqrt()
                <= 2.0 * radius
        })
        .collect();
    println!("{} texels within 2R; {rays} rays each", near.len());
    let points: Vec<[f64; 3]> = near.iter().map(|&x| g0.texels[x].position).collect();
    let tc9 = transfer_at_points(
        &ball,
        sphere,
        &points,
        9,
        4096,
        3,
        SurfaceAlbedo::Uniform([1.0; 3]),
    );

    struct Row {
        total: Rgb,
        occ: Rgb,
        refl: Rgb,
        shadow: Rgb,
        // [variant] × [4, 9] SH, exact receiver normal: (occlusion, reflection)
        exact: Vec<[(Rgb, Rgb); 2]>,
        no: Vec<[(Rgb, Rgb); 2]>,
    }
    let e_of = |c: &[[f64; 9]; 3], n_sh: usize, d: [f64; 3]| -> Rgb {
        let y = sh_basis(d);
        [0, 1, 2].map(|ch| (0..n_sh).map(|k| c[ch][k] * y[k]).sum())
    };
    // Anti-radiance from the irradiance E(ω)/π (paper eq. 12) or from the radiance
    // L(ω) = Σ c_j/Â_l Y_j(ω) (Appendix B.2): k_j weighted by π/Â_l.
    let w_rad: [[f64; 9]; 3] = [[0.0; 9]; 3].map(|_| std::array::from_fn(|k| PI / a[k]));
    let scale = |c: &[[f64; 9]; 3], w: &[[f64; 9]; 3]| -> [[f64; 9]; 3] {
        std::array::from_fn(|ch| std::array::from_fn(|k| c[ch][k] * w[ch][k]))
    };
    let variants: Vec<(&str, Sh, Sh)> = vec![
        ("probe c, irradiance AR (eval)", c_sum, c_sum),
        ("split c, irradiance AR", c_dir, c_env),
        ("probe c, radiance AR (B.2)", c_sum, scale(&c_sum, &w_rad)),
        ("split c, radiance AR (B.2)", c_dir, scale(&c_env, &w_rad)),
    ];
    let rows: Vec<Row> = near
        .iter()
        .enumerate()
        .map(|(p, &x)| {
            let texel = &g0.texels[x];
            let key = mixed_key(2, 902, x as u64);
            let (mut total, mut occ, mut refl, mut shadow) =
                ([0.0; 3], [0.0; 3], [0.0; 3], [0.0; 3]);
            let mut exact = vec![[([0.0; 3], [0.0; 3]); 2]; variants.len()];
            for i in 0..rays {
                let d = to_world(sample_cosine_hemisphere(sobol_2d(key, i)), texel.normal);
                let h0 = t0.closest(texel.position, d, f64::INFINITY, &sign);
                let h1 = t1.closest(texel.position, d, f64::INFINITY, &sign);
                let ld = |t: &Tracer, h: &lightfarm_server::bake::tracer::Hit| {
                    direct_radiance(t, ls, h.point, h.normal, albedo_of(t, h.primitive), min_r2)
                };
                let l0 = h0.as_ref().map_or([0.0; 3], |h| ld(&t0, h));
                let l1 = h1.as_ref().map_or([0.0; 3], |h| ld(&t1, h));
                let on_ball = h1.as_ref().is_some_and(|h| h.primitive >= n_static);
                for c in 0..3 {
                    total[c] += l1[c] - l0[c];
                    if on_ball {
                        occ[c] -= l0[c];
                        refl[c] += l1[c];
                    } else {
                        shadow[c] += l1[c] - l0[c];
                    }
                }
                if on_ball {
                    let ns = h1.as_ref().unwrap().normal;
                    for (s, (_, cr, co)) in variants.iter().enumerate() {
                        for (b, n_sh) in [4usize, 9].iter().enumerate() {
                            let er = e_of(cr, *n_sh, ns);
                            let eo = e_of(co, *n_sh, d);
                            for c in 0..3 {
                                exact[s][b].0[c] -= eo[c] / PI;
                                exact[s][b].1[c] += rho_o[c] * er[c] / PI;
                            }
                        }
                    }
                }
            }
            let f = |v: Rgb| [0, 1, 2].map(|c| texel.albedo[c] * v[c] / rays as f64);
            let exact: Vec<_> = exact
                .into_iter()
                .map(|s| s.map(|(o, r)| (f(o), f(r))))
                .collect();
            // Intermediate normal, the baked quantity at the texel itself.
            let to_c: [f64; 3] = std::array::from_fn(|k| centre[k] - texel.position[k]);
            let dist = to_c.iter().map(|x| x * x).sum::<f64>().sqrt();
            let lambert = (0..3)
                .map(|k| to_c[k] * texel.normal[k])
                .sum::<f64>()
                .max(0.0)
                / dist;
            let t = &tc9.reflection[p * 27..p * 27 + 9];
            let k = &tc9.occlusion[p * 9..p * 9 + 9];
            let mut no = vec![[([0.0; 3], [0.0; 3]); 2]; variants.len()];
            for (s, (_, cr, co)) in variants.iter().enumerate() {
                for (b, n_sh) in [4usize, 9].iter().enumerate() {
                    for c in 0..3 {
                        let o: f64 = (0..*n_sh).map(|j| co[c][j] * k[j]).sum();
                        let r: f64 = (0..*n_sh).map(|j| cr[c][j] * rho_o[c] * t[j]).sum();
                        no[s][b].0[c] = -texel.albedo[c] * lambert * o;
                        no[s][b].1[c] = texel.albedo[c] * lambert * r;
                    }
                }
            }
            Row {
                total: f(total),
                occ: f(occ),
                refl: f(refl),
                shadow: f(shadow),
                exact,
                no,
            }
        })
        .collect();

    let col = |f: &dyn Fn(&Row) -> Rgb| rows.iter().map(f).collect::<Vec<Rgb>>();
    let total = col(&|r| r.total);
    println!(
        "reference delta ‖·‖: total {:.4}, occlusion {:.4}, reflection {:.4}, shadow {:.4}",
        norm(&total),
        norm(&col(&|r| r.occ)),
        norm(&col(&|r| r.refl)),
        norm(&col(&|r| r.shadow))
    );
    let mean = |v: &[Rgb]| [0, 1, 2].map(|c| v.iter().map(|x| x[c]).sum::<f64>() / v.len() as f64);
    println!("mean reference delta {:?}", mean(&total));
    println!(
        "shadow term alone: relative L2 of (occ + refl) vs total = {:.4}",
        rel(&rows
            .iter()
            .map(|r| (add(r.occ, r.refl), r.total))
            .collect::<Vec<_>>())
    );
    for (s, (split, _, _)) in variants.iter().enumerate() {
        for (b, n_sh) in [4, 9].iter().enumerate() {
            for (name, pick) in [("exact-n", 0), ("n_o", 1)] {
                let m = |r: &Row| if pick == 0 { r.exact[s][b] } else { r.no[s][b] };
                let pairs_total: Vec<(Rgb, Rgb)> = rows
                    .iter()
                    .map(|r| (add(m(r).0, m(r).1), r.total))
                    .collect();
                let pairs_model: Vec<(Rgb, Rgb)> = rows
                    .iter()
                    .map(|r| (add(m(r).0, m(r).1), add(r.occ, r.refl)))
                    .collect();
                let occ: Vec<(Rgb, Rgb)> = rows.iter().map(|r| (m(r).0, r.occ)).collect();
                let refl: Vec<(Rgb, Rgb)> = rows.iter().map(|r| (m(r).1, r.refl)).collect();
                println!(
                    "{split}, {n_sh} SH, {name}: vs total {:.4}; vs occ+refl {:.4}; occlusion term {:.4}; reflection term {:.4}; mean {:?}",
                    rel(&pairs_total),
                    rel(&pairs_model),
                    rel(&occ),
                    rel(&refl),
                    mean(&pairs_total.iter().map(|p| p.0).collect::<Vec<_>>()).map(|x| (x * 1e4).round() / 1e4)
                );
            }
        }
    }
    Ok(())
}
