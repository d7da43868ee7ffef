//! Tests of the bounce modes ([`Bounces`], `runtime/mod.rs` and `runtime/krylov.rs`): `Fixed`
//! against explicit sums of bounces, `Converged` against many bounces within its tolerance and
//! in fewer applications, refusal of a gain-one operator (never a loop, never NaN), `Feedback`
//! converging to `Converged`, `Warm` as accurate as `Converged` at one application while lights
//! hold still and fewer while they move, and bit-identical `Converged` and `Warm` at one and two
//! threads.

use super::*;
use crate::compare::relative_l2;

/// `Σ_{k=1..n} A^k ld` in f64 with `one` the dense one-bounce reference of the method.
fn reference_bounces(
    bundle: &Bundle,
    ld: &[[f32; 3]],
    n: u32,
    one: fn(&Bundle, &[[f32; 3]]) -> Vec<[f64; 3]>,
) -> Vec<[f64; 3]> {
    let mut light: Vec<[f32; 3]> = ld.to_vec();
    let mut sum = vec![[0.0f64; 3]; ld.len()];
    for _ in 0..n {
        let next = one(bundle, &light);
        for (s, v) in sum.iter_mut().zip(&next) {
            for c in 0..3 {
                s[c] += v[c];
            }
        }
        light = next.iter().map(|v| v.map(|x| x as f32)).collect();
    }
    sum
}

/// A bundle whose one-bounce gain is about `gain` for every method: every operator value is
/// scaled so the dense operator's largest row sum times the largest albedo is `gain`.
fn with_gain(mut b: Bundle, gain: f32) -> Bundle {
    let f = b.full.as_mut().expect("a full operator");
    let n = f.n as usize;
    let row_max = (0..n)
        .map(|i| {
            f.values[f.row_start[i] as usize..f.row_start[i + 1] as usize]
                .iter()
                .sum::<f32>()
        })
        .fold(0.0f32, f32::max);
    let rho_max = b
        .layout
        .albedo
        .iter()
        .flatten()
        .fold(0.0f32, |m, &x| m.max(x));
    let scale = gain / (row_max * rho_max);
    for v in &mut f.values {
        *v *= scale;
    }
    b
}

#[test]
fn fixed_bounces_equal_the_sum_of_explicit_bounces() {
    let mut rng = Lcg(41);
    // MRT (traced and lightfield transport), DRT and the dense operator, against f64
    // references iterated by hand.
    let (t, l) = (traced(&mut rng), lightfield(&mut rng));
    let cases: Vec<(Bundle, Method, fn(&Bundle, &[[f32; 3]]) -> Vec<[f64; 3]>)> = vec![
        (bundle(&mut rng, Some(t), false), Method::Mrt, reference_mrt),
        (bundle(&mut rng, Some(l), false), Method::Mrt, reference_mrt),
        (
            drt_bundle(&mut rng, true, true, false),
            Method::Drt,
            reference_drt,
        ),
        (
            with_gain(bundle(&mut rng, None, true), 0.7),
            Method::Full,
            reference_full,
        ),
    ];
    for (b, method, one) in cases {
        let n = b.layout.n_texels();
        let ld = direct(&mut rng, n);
        let mut rt = Runtime::new(b.clone());
        let mut out = IndirectLight::default();
        for bounces in [1u32, 2, 4] {
            let mode = if bounces == 1 {
                Bounces::One
            } else {
                Bounces::Fixed(bounces)
            };
            let applied = rt.apply(method, mode, &ld, &mut out).unwrap();
            assert_eq!(applied.bounces, bounces, "{method:?}");
            let want = reference_bounces(&b, &ld.radiance, bounces, one);
            // Relative to the largest value: the iterated random operators grow.
            let scale = want.iter().flatten().fold(1.0f64, |m, &x| m.max(x.abs()));
            for (g, w) in out.radiance.iter().zip(&want) {
                for c in 0..3 {
                    assert!(
                        (g[c] as f64 - w[c]).abs() <= 2e-5 * scale,
                        "{method:?} {bounces} bounces: {} vs {}",
                        g[c],
                        w[c]
                    );
                }
            }
        }
        assert_eq!(
            rt.apply(method, Bounces::Fixed(0), &ld, &mut out),
            Err(ApplyError::NoBounces)
        );
    }
}

#[test]
fn converged_matches_the_sum_of_many_bounces_within_its_tolerance_in_fewer_applications() {
    let mut rng = Lcg(43);
    for (b, method, gain) in [
        (
            with_gain(bundle(&mut rng, None, true), 0.6),
            Method::Full,
            0.6,
        ),
        (
            with_gain(bundle(&mut rng, None, true), 0.9),
            Method::Full,
            0.9,
        ),
    ] {
        let ld = direct(&mut rng, b.layout.n_texels());
        let mut rt = Runtime::new(b);
        let mut converged = IndirectLight::default();
        let mut many = IndirectLight::default();
        rt.apply(method, Bounces::Fixed(400), &ld, &mut many)
            .unwrap();
        let e_all = energy(&many.radiance);
        let mut previous = 0;
        for tolerance in [1e-2f32, 1e-3, 1e-5] {
            let applied = rt
                .apply(
                    method,
                    Bounces::Converged { tolerance },
                    &ld,
                    &mut converged,
                )
                .unwrap();
            assert!(applied.remaining_fraction <= tolerance, "{applied:?}");
            assert!(applied.bounces >= previous, "{applied:?}");
            previous = applied.bounces;
            let err = relative_l2(&converged.radiance, &many.radiance);
            let rest = (e_all - energy(&converged.radiance)).abs() / e_all;
            assert!(
                err <= 3.0 * tolerance as f64 + 1e-5 && rest <= 3.0 * tolerance as f64 + 1e-5,
                "gain {gain}, tolerance {tolerance}: relative L2 {err}, energy {rest}"
            );
            // Summing bounces one by one to the same error takes about
            // log(tolerance · (1 − λ)) / log(λ) bounces; GMRES needs at most half.
            let series = ((tolerance as f64 * (1.0 - gain)).ln() / gain.ln()).ceil() as u32;
            assert!(
                applied.bounces * 2 <= series,
                "gain {gain}, tolerance {tolerance}: {} applications vs {series} bounces",
                applied.bounces
            );
        }
    }
    let mut rng = Lcg(44);
    let b = with_gain(bundle(&mut rng, None, true), 0.6);
    let ld = direct(&mut rng, b.layout.n_texels());
    let mut rt = Runtime::new(b);
    let mut out = IndirectLight::default();
    for bad in [0.0f32, 1.0, -1.0, f32::NAN] {
        assert!(matches!(
            rt.apply(
                Method::Full,
                Bounces::Converged { tolerance: bad },
                &ld,
                &mut out
            ),
            Err(ApplyError::BadTolerance(_))
        ));
    }
}

#[test]
fn converged_equals_many_explicit_bounces_for_mrt_and_drt() {
    let mut rng = Lcg(45);
    let (t, l) = (traced(&mut rng), lightfield(&mut rng));
    for (b, method) in [
        (bundle(&mut rng, Some(t), false), Method::Mrt),
        (bundle(&mut rng, Some(l), false), Method::Mrt),
        (drt_bundle(&mut rng, true, true, false), Method::Drt),
    ] {
        let ld = direct(&mut rng, b.layout.n_texels());
        let mut rt = Runtime::new(b);
        let (mut converged, mut many) = (IndirectLight::default(), IndirectLight::default());
        match rt.apply(
            method,
            Bounces::Converged { tolerance: 1e-4 },
            &ld,
            &mut converged,
        ) {
            Ok(applied) => {
                rt.apply(method, Bounces::Fixed(300), &ld, &mut many)
                    .unwrap();
                let err = relative_l2(&converged.radiance, &many.radiance);
                assert!(err <= 5e-4, "{method:?}: {err} after {applied:?}");
            }
            // The random operators may have gain ≥ 1 (no all-bounce light): refused.
            Err(ApplyError::NotConverging { .. }) => {}
            Err(e) => panic!("{method:?}: {e}"),
        }
    }
}

#[test]
fn an_operator_with_gain_one_is_refused_not_looped_and_never_nan() {
    let mut rng = Lcg(47);
    for gain in [1.0f32, 1.5, 0.9999] {
        // A perfect reflector (albedo 1) whose every row sums to `gain`: the operator's
        // gain is exactly `gain`, like a closed white room.
        let mut b = bundle(&mut rng, None, true);
        let f = b.full.as_mut().unwrap();
        let mut rows = SparseRows {
            n: f.n,
            row_start: vec![0],
            cols: vec![],
            values: vec![],
        };
        for i in 0..f.n as usize {
            let (s, e) = (f.row_start[i] as usize, f.row_start[i + 1] as usize);
            let sum: f32 = f.values[s..e].iter().sum();
            if sum > 0.0 {
                rows.cols.extend_from_slice(&f.cols[s..e]);
                rows.values
                    .extend(f.values[s..e].iter().map(|v| v * gain / sum));
            } else {
                rows.cols.push(i as u32);
                rows.values.push(gain);
            }
            rows.row_start.push(rows.cols.len() as u32);
        }
        *f = rows;
        b.layout.albedo.fill([1.0; 3]);
        let ld = direct(&mut rng, b.layout.n_texels());
        let mut rt = Runtime::new(b);
        let mut out = IndirectLight::default();
        let err = rt
            .apply(Method::Full, Bounces::default(), &ld, &mut out)
            .unwrap_err();
        match err {
            ApplyError::NotConverging { bounces, .. } => {
                assert!(bounces <= MAX_BOUNCES, "{bounces}")
            }
            ApplyError::NonFinite { .. } => {}
            other => panic!("gain {gain}: {other}"),
        }
        assert!(err.to_string().contains("bounces"), "{err}");
        assert!(out.radiance.iter().flatten().all(|&x| x == 0.0));
    }
}

#[test]
fn feedback_converges_to_converged_and_stays_bounded_while_lights_move() {
    let mut rng = Lcg(53);
    for (b, method) in [
        (with_gain(bundle(&mut rng, None, true), 0.65), Method::Full),
        (drt_bundle(&mut rng, false, true, false), Method::Drt),
    ] {
        let n = b.layout.n_texels();
        let ld = direct(&mut rng, n);
        let mut rt = Runtime::new(b);
        let tight = Bounces::Converged { tolerance: 1e-6 };
        let mut converged = IndirectLight::default();
        if rt.apply(method, tight, &ld, &mut converged).is_err() {
            // The random DRT operators may have gain ≥ 1; then feedback is not defined
            // either. The dense case always runs.
            assert_eq!(method, Method::Drt);
            continue;
        }
        let mut out = IndirectLight::default();
        let e_conv = energy(&converged.radiance);
        let mut frames_to_1pct = None;
        for frame in 1..=200 {
            rt.apply(method, Bounces::Feedback, &ld, &mut out).unwrap();
            let diff: f64 = out
                .radiance
                .iter()
                .zip(&converged.radiance)
                .map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).abs() as f64).sum::<f64>())
                .sum();
            if frames_to_1pct.is_none() && diff <= 0.01 * e_conv {
                frames_to_1pct = Some(frame);
            }
        }
        let frames = frames_to_1pct.expect("feedback reaches 1% of Converged");
        assert!(frames < 60, "{method:?}: {frames} frames");
        for (a, b) in out.radiance.iter().zip(&converged.radiance) {
            for c in 0..3 {
                assert!(
                    (a[c] - b[c]).abs() <= 1e-4 * (1.0 + b[c].abs()),
                    "{a:?} {b:?}"
                );
            }
        }
        // A light that jumps every frame: feedback stays within the converged light of the
        // brightest frame (all light is non-negative, the operator monotone).
        rt.reset_feedback();
        let lights: Vec<DirectLight> = (0..8).map(|_| direct(&mut rng, n)).collect();
        let mut bound = 0.0f64;
        for l in &lights {
            rt.apply(method, tight, l, &mut converged).unwrap();
            bound = bound.max(energy(&converged.radiance));
        }
        let brightest = DirectLight {
            radiance: (0..n)
                .map(|t| {
                    std::array::from_fn(|c| {
                        lights.iter().map(|l| l.radiance[t][c]).fold(0.0, f32::max)
                    })
                })
                .collect(),
        };
        rt.apply(method, tight, &brightest, &mut converged).unwrap();
        let ceiling = energy(&converged.radiance);
        assert!(ceiling >= bound);
        for frame in 0..400 {
            rt.apply(method, Bounces::Feedback, &lights[frame % 8], &mut out)
                .unwrap();
            let e = energy(&out.radiance);
            assert!(
                e.is_finite() && e <= ceiling * (1.0 + 1e-4),
                "frame {frame}: {e}"
            );
        }
    }
}

/// `ld` with every texel changed by up to ±`fraction` of itself (a light that moved a little).
fn nudged(rng: &mut Lcg, ld: &DirectLight, fraction: f32) -> DirectLight {
    DirectLight {
        radiance: ld
            .radiance
            .iter()
            .map(|v| v.map(|x| x * (1.0 + rng.range(-fraction, fraction))))
            .collect(),
    }
}

#[test]
fn warm_is_as_accurate_as_converged_and_costs_one_application_while_lights_hold_still() {
    let mut rng = Lcg(61);
    let t = traced(&mut rng);
    let tolerance = 1e-3f32;
    let warm = Bounces::Warm { tolerance };
    let cold = Bounces::Converged { tolerance };
    let mut cases = 0;
    for (b, method) in [
        (with_gain(bundle(&mut rng, None, true), 0.65), Method::Full),
        (with_gain(bundle(&mut rng, None, true), 0.9), Method::Full),
        (bundle(&mut rng, Some(t), false), Method::Mrt),
        (drt_bundle(&mut rng, false, true, false), Method::Drt),
        (drt_bundle(&mut rng, true, true, false), Method::Drt),
    ] {
        // Darker albedo where the random operators would reflect more than they receive.
        let mut b = b;
        if method != Method::Full {
            for rho in b.layout.albedo.iter_mut().flatten() {
                *rho *= 0.3;
            }
        }
        let n = b.layout.n_texels();
        let mut rt = Runtime::new(b);
        let ld = direct(&mut rng, n);
        let mut truth = IndirectLight::default();
        let tight = Bounces::Converged { tolerance: 1e-6 };
        if rt.apply(method, tight, &ld, &mut truth).is_err() {
            // Random DRT/MRT operators may have gain ≥ 1: Warm must refuse them too.
            rt.reset_feedback();
            let mut out = IndirectLight::default();
            assert!(rt.apply(method, warm, &ld, &mut out).is_err(), "{method:?}");
            continue;
        }
        cases += 1;
        // Without a previous answer Warm is a cold Converged solve, bit for bit.
        let (mut c, mut w) = (IndirectLight::default(), IndirectLight::default());
        rt.reset_feedback();
        let applied_cold = rt.apply(method, cold, &ld, &mut c).unwrap();
        rt.reset_feedback();
        let applied_first = rt.apply(method, warm, &ld, &mut w).unwrap();
        assert_eq!(c, w, "{method:?}");
        assert_eq!(applied_cold, applied_first);
        // Lights holding still: one application (two on the first still frame, whose guess
        // the cold solve left just inside the tolerance), as accurate as Converged.
        for still in 0..5 {
            let applied = rt.apply(method, warm, &ld, &mut w).unwrap();
            let most = if still == 0 { 3 } else { 1 };
            assert!(applied.bounces <= most, "{method:?} {still}: {applied:?}");
            assert!(applied.remaining_fraction <= tolerance);
            let err = relative_l2(&w.radiance, &truth.radiance);
            assert!(err <= 2.0 * tolerance as f64, "{method:?}: {err}");
        }
        // A light that moves a little every frame: within the tolerance of each frame's own
        // light (1% per texel a frame), in fewer applications than solving cold.
        // Per frame: Warm on `rt`, then Converged and the yardstick on a copy (so they leave
        // Warm's guess alone); each frame within 3 × the tolerance. Returns the applications
        // of Warm and of Converged.
        let follow = |rt: &mut Runtime, lights: &mut dyn Iterator<Item = DirectLight>| {
            let (mut warm_apps, mut cold_apps) = (0, 0);
            let (mut c, mut w, mut truth) = Default::default();
            for (frame, light) in lights.enumerate() {
                let applied = rt.apply(method, warm, &light, &mut w).unwrap();
                let mut rt_cold = rt.clone();
                cold_apps += rt_cold.apply(method, cold, &light, &mut c).unwrap().bounces;
                rt_cold.apply(method, tight, &light, &mut truth).unwrap();
                warm_apps += applied.bounces;
                let err = relative_l2(&w.radiance, &truth.radiance);
                assert!(
                    err <= 3.0 * tolerance as f64,
                    "{method:?} frame {frame}: {err} after {applied:?}"
                );
            }
            (warm_apps, cold_apps)
        };
        let mut light = ld.clone();
        let nudges: Vec<DirectLight> = (0..12)
            .map(|_| {
                light = nudged(&mut rng, &light, 0.01);
                light.clone()
            })
            .collect();
        let (warm_apps, cold_apps) = follow(&mut rt, &mut nudges.into_iter());
        assert!(
            warm_apps < cold_apps,
            "{method:?}: {warm_apps} vs {cold_apps}"
        );
        // A light moving steadily (direct light linear in time): the guess extrapolated from
        // the last two answers leaves little to solve.
        let step = direct(&mut rng, n);
        let mut ramp = (0..12).map(|frame| {
            let t = 0.02 * frame as f32;
            DirectLight {
                radiance: ld
                    .radiance
                    .iter()
                    .zip(&step.radiance)
                    .map(|(a, d)| std::array::from_fn(|c| a[c] + t * d[c]))
                    .collect(),
            }
        });
        let (warm_apps, cold_apps) = follow(&mut rt, &mut ramp);
        assert!(
            2 * warm_apps <= cold_apps,
            "{method:?} ramp: {warm_apps} vs {cold_apps}"
        );
        // A jump to unrelated light, and to darkness: still within the tolerance.
        for jump in [
            direct(&mut rng, n),
            DirectLight {
                radiance: vec![[0.0; 3]; n],
            },
        ] {
            rt.apply(method, warm, &jump, &mut w).unwrap();
            rt.clone().apply(method, tight, &jump, &mut truth).unwrap();
            if energy(&truth.radiance) > 1e-20 {
                let err = relative_l2(&w.radiance, &truth.radiance);
                assert!(err <= 3.0 * tolerance as f64, "{method:?} jump: {err}");
            } else {
                // Darkness: exactly none.
                assert!(w.radiance.iter().flatten().all(|&x| x == 0.0), "{method:?}");
            }
        }
        // apply_delta moves the answer Warm starts from: after it, holding still costs one
        // application again and stays accurate.
        let (l1, l2) = (direct(&mut rng, n), direct(&mut rng, n));
        let mut out = IndirectLight::default();
        rt.apply(method, cold, &l1, &mut out).unwrap();
        let change = DirectLight {
            radiance: l1
                .radiance
                .iter()
                .zip(&l2.radiance)
                .map(|(a, b)| [b[0] - a[0], b[1] - a[1], b[2] - a[2]])
                .collect(),
        };
        rt.apply_delta(method, warm, &change, &mut out).unwrap();
        let applied = rt.apply(method, warm, &l2, &mut w).unwrap();
        rt.clone().apply(method, tight, &l2, &mut truth).unwrap();
        assert!(applied.bounces <= 3, "{method:?}: {applied:?}");
        let err = relative_l2(&w.radiance, &truth.radiance);
        assert!(
            err <= 3.0 * tolerance as f64,
            "{method:?} after apply_delta: {err}"
        );
        for bad in [0.0f32, 1.0, f32::NAN] {
            assert!(matches!(
                rt.apply(method, Bounces::Warm { tolerance: bad }, &l2, &mut w),
                Err(ApplyError::BadTolerance(_))
            ));
        }
    }
    assert!(cases >= 4, "{cases}");
}

#[test]
fn warm_refuses_an_operator_with_gain_one() {
    let mut rng = Lcg(67);
    let mut b = bundle(&mut rng, None, true);
    let f = b.full.as_mut().unwrap();
    // Every row sums to 1 with albedo 1: a closed white room.
    for i in 0..f.n as usize {
        let (s, e) = (f.row_start[i] as usize, f.row_start[i + 1] as usize);
        let sum: f32 = f.values[s..e].iter().sum();
        if sum > 0.0 {
            f.values[s..e].iter_mut().for_each(|v| *v /= sum);
        }
    }
    b.layout.albedo.fill([1.0; 3]);
    let ld = direct(&mut rng, b.layout.n_texels());
    let mut rt = Runtime::new(b);
    let mut out = IndirectLight::default();
    for _ in 0..3 {
        let err = rt
            .apply(
                Method::Full,
                Bounces::Warm { tolerance: 1e-3 },
                &ld,
                &mut out,
            )
            .unwrap_err();
        assert!(
            matches!(
                err,
                ApplyError::NotConverging { .. } | ApplyError::NonFinite { .. }
            ),
            "{err}"
        );
        assert!(out.radiance.iter().flatten().all(|&x| x == 0.0));
    }
}

/// A pool of `threads` threads and a runtime of `b` that runs its blocks on it (more than one).
#[cfg(feature = "rayon")]
pub(super) fn runtime_on(threads: usize, b: &Bundle) -> (rayon::ThreadPool, Runtime) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let mut rt = Runtime::new(b.clone());
    rt.set_parallel(threads > 1);
    (pool, rt)
}

#[cfg(feature = "rayon")]
#[test]
fn warm_is_bit_identical_at_one_and_two_threads() {
    let mut rng = Lcg(71);
    let b = with_gain(bundle(&mut rng, None, true), 0.65);
    let lights: Vec<DirectLight> = {
        let first = direct(&mut rng, b.layout.n_texels());
        let mut v = vec![first.clone(), first.clone()];
        v.push(nudged(&mut rng, &first, 0.1));
        v.push(direct(&mut rng, b.layout.n_texels()));
        v
    };
    let mut outputs = Vec::new();
    for threads in [1usize, 2] {
        let (pool, mut rt) = runtime_on(threads, &b);
        let mut run = Vec::new();
        for l in &lights {
            let mut out = IndirectLight::default();
            let a = pool
                .install(|| rt.apply(Method::Full, Bounces::Warm { tolerance: 1e-3 }, l, &mut out))
                .unwrap();
            run.push((a, out));
        }
        outputs.push(run);
    }
    assert_eq!(outputs[0], outputs[1]);
}

#[cfg(feature = "rayon")]
#[test]
fn converged_is_bit_identical_at_one_and_two_threads() {
    let mut rng = Lcg(59);
    let b = drt_bundle(&mut rng, true, true, false);
    let ld = direct(&mut rng, b.layout.n_texels());
    let mut outputs = Vec::new();
    for threads in [1usize, 2] {
        let (pool, mut rt) = runtime_on(threads, &b);
        let mut out = IndirectLight::default();
        pool.install(|| rt.apply(Method::Drt, Bounces::Fixed(6), &ld, &mut out))
            .unwrap();
        outputs.push(out);
        let mut out = IndirectLight::default();
        let converged = pool.install(|| rt.apply(Method::Drt, Bounces::default(), &ld, &mut out));
        outputs.push(IndirectLight {
            radiance: if converged.is_ok() {
                out.radiance
            } else {
                vec![]
            },
        });
    }
    assert_eq!(outputs[0], outputs[2]);
    assert_eq!(outputs[1], outputs[3]);
}

/// `Converged` with MRT runs in coefficient space (`runtime/reduced.rs`): the same light as the
/// texel path's GMRES and as many explicit bounces, within the tolerance and in about as many
/// applications, for every transport (a lightfield keeps the texel path), with an albedo per
/// texel (one matrix per channel) and one to three albedos per block (one matrix for the three
/// channels per albedo); a second call allocates nothing and repeats the same bits.
#[test]
fn reduced_converged_matches_the_texel_path_and_many_bounces() {
    let mut rng = Lcg(61);
    let transports = [
        Some(traced(&mut rng)),
        Some(compact(&mut rng)),
        Some(lightfield(&mut rng)),
        None,
        Some(factored(&mut rng)),
    ];
    for transport in transports {
        for albedos_per_block in [0usize, 1, 2, 3] {
            // The three-albedo case draws from a generator of its own (the others' bundles
            // stay what they were).
            let mut own = Lcg(67);
            let rng = if albedos_per_block == 3 {
                &mut own
            } else {
                &mut rng
            };
            let mut b = bundle(rng, transport.clone(), false);
            if albedos_per_block > 0 {
                for blk in b.blocks.clone() {
                    let start = blk.texel_offset as usize;
                    let n = b.shapes[blk.shape as usize].u_b.rows as usize;
                    let (first, middle, last) = (
                        b.layout.albedo[start],
                        b.layout.albedo[start + 1],
                        b.layout.albedo[start + n - 1],
                    );
                    for (i, a) in b.layout.albedo[start..start + n].iter_mut().enumerate() {
                        // Groups of texels by albedo: all, halves, or thirds.
                        *a = match (albedos_per_block, 3 * i / n) {
                            (2, 1) | (2, 2) if i >= n / 2 => last,
                            (3, 1) => middle,
                            (3, 2) => last,
                            _ => first,
                        };
                    }
                }
            }
            let ld = direct(rng, b.layout.n_texels());
            let case = format!(
                "{:?}, {albedos_per_block} albedos per block",
                b.transport.as_ref().map(std::mem::discriminant)
            );
            // The random operators may keep more light than they receive: dim the albedo
            // until the light converges.
            let mut rt = Runtime::new(b.clone());
            let tolerance = Bounces::Converged { tolerance: 1e-5 };
            let mut texel = IndirectLight::default();
            for _ in 0..8 {
                rt.set_reduced_bounces(false);
                if rt.apply(Method::Mrt, tolerance, &ld, &mut texel).is_ok() {
                    break;
                }
                b.layout.albedo.iter_mut().flatten().for_each(|a| *a *= 0.5);
                rt = Runtime::new(b.clone());
            }
            let texel_applied = rt
                .apply(Method::Mrt, tolerance, &ld, &mut texel)
                .unwrap_or_else(|e| panic!("{case}: {e}"));
            rt.set_reduced_bounces(true);
            let (mut reduced, mut many) = (IndirectLight::default(), IndirectLight::default());
            let applied = rt.apply(Method::Mrt, tolerance, &ld, &mut reduced).unwrap();
            rt.apply(Method::Mrt, Bounces::Fixed(400), &ld, &mut many)
                .unwrap();
            assert_reduced_matches(&case, (&reduced, applied), (&texel, texel_applied), &many);
            // The energies the reduced path checks light with are those of the texel light.
            let lightfield = matches!(b.transport, Some(TransportOps::Lightfield(_)));
            let energies = rt.reduced_energies();
            assert_eq!(energies.is_none(), lightfield, "{case}: which path solved");
            let (e1, e) = energies.unwrap_or_default();
            let mut one = IndirectLight::default();
            rt.apply(Method::Mrt, Bounces::One, &ld, &mut one).unwrap();
            for c in (0..3).filter(|_| !lightfield) {
                let channel =
                    |v: &IndirectLight| v.radiance.iter().map(|x| x[c] as f64).sum::<f64>();
                let (want1, want) = (channel(&one), channel(&reduced));
                let scale = want1.abs().max(want.abs()).max(1e-9);
                assert!(
                    (e1[c] - want1).abs() <= 1e-4 * scale && (e[c] - want).abs() <= 1e-4 * scale,
                    "{case}: channel {c}: {e1:?} / {e:?} against {want1} / {want}"
                );
            }
            let first = reduced.clone();
            let before = allocs();
            rt.apply(Method::Mrt, tolerance, &ld, &mut reduced).unwrap();
            assert_eq!(
                allocs(),
                before,
                "{case}: the second reduced solve allocated"
            );
            assert_eq!(reduced, first, "{case}: not deterministic");
        }
    }
}
