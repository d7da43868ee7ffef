//! Every entry point called as C calls it, on a hand-built two-texel bundle whose MRT output is
//! known exactly: results, then every error path (garbage bytes, wrong lengths, NULL
//! pointers, unknown methods, missing operators, invalid lights) and the last-error contract;
//! then the bounce modes (all bounces by default, one, feedback) against the geometric series
//! of the same operator. Last, the one-light entry points (reach spans, direct light on spans)
//! and their error paths. The texel layout and atlas queries are in `layout.rs`, placing
//! dynamic objects in `poses.rs`; `common` holds the runtime guard and the last-error reader.

use std::ptr::{null, null_mut};

use lightfarm::*;
use lightfarm_client::{direct_from_point_lights_averaged, Light, Occluders};
use lightfarm_proto::bundle::Bundle;
use lightfarm_proto::lights::LightKind;
use lightfarm_proto::testing::{drt_bundle, Lcg};

mod common;

use common::{last_error, Rt, OK};

/// `testing::two_texel_bundle`: MRT gives `ρ_t · (l_0 + l_1) / 2` at each texel.
fn two_texel_bundle() -> Vec<u8> {
    lightfarm_proto::testing::two_texel_bundle().encode()
}

impl Rt {
    /// The two-texel bundle, set to one bounce (the exact values below are one bounce's).
    fn load() -> Rt {
        let rt = Rt::load_default();
        // SAFETY: live runtime.
        assert_eq!(
            unsafe { lf_runtime_set_bounces(rt.0, LfBounces::One as i32, 0.0) },
            OK
        );
        rt
    }

    /// The two-texel bundle with the runtime's default bounce mode (all bounces).
    fn load_default() -> Rt {
        let bytes = two_texel_bundle();
        // SAFETY: `bytes` is live for the call.
        let rt = unsafe { lf_runtime_new(bytes.as_ptr(), bytes.len()) };
        assert!(!rt.is_null(), "hand-built bundle loads: {}", last_error());
        Rt(rt)
    }

    fn apply(&self, method: i32, direct: &[f32], out: &mut [f32]) -> i32 {
        // SAFETY: live runtime; the slices are live for the call.
        unsafe {
            lf_runtime_apply(
                self.0,
                method,
                direct.as_ptr(),
                direct.len(),
                out.as_mut_ptr(),
                out.len(),
            )
        }
    }

    fn direct(&self, lights: &[LfPointLight], out: &mut [f32]) -> i32 {
        // SAFETY: live runtime; the slices are live for the call.
        unsafe {
            lf_runtime_direct_from_point_lights(
                self.0,
                lights.as_ptr(),
                lights.len(),
                out.as_mut_ptr(),
                out.len(),
            )
        }
    }
}

const DIRECT: [f32; 6] = [1.0, 2.0, 3.0, 3.0, 4.0, 5.0];
/// ρ_t · (l_0 + l_1) / 2 = ρ_t · (2, 3, 4), exact in f32.
const MRT: [f32; 6] = [1.0, 1.5, 2.0, 0.5, 1.5, 4.0];

#[test]
fn a_valid_bundle_loads_and_applies_mrt_exactly() {
    let rt = Rt::load();
    // SAFETY: live runtime.
    unsafe {
        assert_eq!(lf_runtime_texel_count(rt.0), 2);
        assert!(!lf_runtime_has_drt(rt.0));
        assert!(!lf_runtime_has_full(rt.0));
    }
    let mut out = [f32::NAN; 6];
    assert_eq!(rt.apply(LfMethod::Mrt as i32, &DIRECT, &mut out), OK);
    assert_eq!(out, MRT);
    // In place: the direct light is read before the output is written.
    let mut inout = DIRECT;
    let p = inout.as_mut_ptr();
    // SAFETY: live runtime; `inout` is 6 floats, passed as both buffers.
    let status = unsafe { lf_runtime_apply(rt.0, 0, p, 6, p, 6) };
    assert_eq!(status, OK);
    assert_eq!(inout, MRT);
}

#[test]
fn direct_light_is_the_clients_texel_average() {
    let rt = Rt::load();
    let lights = [
        LfPointLight {
            position: [0.5, 1.0, 0.25],
            intensity: [2.0, 1.0, 0.5],
        },
        LfPointLight {
            position: [0.0, 0.5, 0.0],
            intensity: [0.0, 3.0, 0.0],
        },
    ];
    let mut out = [f32::NAN; 6];
    assert_eq!(rt.direct(&lights, &mut out), OK);
    let bundle = Bundle::decode(&two_texel_bundle()).unwrap();
    let as_light = |l: &LfPointLight| Light {
        kind: LightKind::Point,
        position: l.position.map(f64::from),
        intensity: l.intensity.map(f64::from),
    };
    let want = direct_from_point_lights_averaged(
        &bundle.layout,
        &Occluders::from_layout(&bundle.layout),
        &lights.iter().map(as_light).collect::<Vec<_>>(),
        LF_DIRECT_SAMPLES_PER_EDGE,
    );
    assert_eq!(out.as_slice(), want.radiance.as_flattened());
    // Red comes from the first light only, a quarter metre off its foot (r² ≈ 1.06): about
    // ρ/π · I · cosθ/r² = 0.5/π · 2 · 0.91 ≈ 0.29 at the texel centre.
    assert!((0.25..0.32).contains(&out[0]), "{}", out[0]);
    // No lights: no direct light.
    let mut dark = [f32::NAN; 6];
    // SAFETY: live runtime; NULL lights with a zero count.
    let status =
        unsafe { lf_runtime_direct_from_point_lights(rt.0, null(), 0, dark.as_mut_ptr(), 6) };
    assert_eq!(status, OK);
    assert_eq!(dark, [0.0; 6]);
}

#[test]
fn garbage_bytes_give_null_and_say_why() {
    let garbage = b"definitely not a lightfarm bundle";
    // SAFETY: `garbage` is live for the call.
    let rt = unsafe { lf_runtime_new(garbage.as_ptr(), garbage.len()) };
    assert!(rt.is_null());
    assert_eq!(
        last_error(),
        "lf_runtime_new: cannot load bundle: not a lightfarm bundle (bad magic)"
    );
    // A valid bundle cut short is refused too.
    let bytes = two_texel_bundle();
    // SAFETY: a prefix of `bytes`.
    assert!(unsafe { lf_runtime_new(bytes.as_ptr(), bytes.len() - 1) }.is_null());
    assert!(last_error().starts_with("lf_runtime_new: cannot load bundle: "));
    // SAFETY: NULL bytes.
    unsafe {
        assert!(lf_runtime_new(null(), 10).is_null());
        assert_eq!(last_error(), "lf_runtime_new: bytes is NULL");
        assert!(lf_runtime_new(null(), 0).is_null(), "no bytes is no bundle");
    }
}

#[test]
fn last_error_truncates_at_the_capacity_and_reports_the_size() {
    let garbage = [0u8; 4];
    // SAFETY: `garbage` is live for the call.
    assert!(unsafe { lf_runtime_new(garbage.as_ptr(), 4) }.is_null());
    let full = last_error();
    let mut small = [0x55u8; 8];
    // SAFETY: 8 writable bytes.
    let needed = unsafe { lf_last_error(small.as_mut_ptr().cast(), small.len()) };
    assert_eq!(needed, full.len() + 1);
    assert_eq!(&small[..7], &full.as_bytes()[..7]);
    assert_eq!(small[7], 0);
    // SAFETY: NULL buffer: nothing written whatever the capacity.
    assert_eq!(unsafe { lf_last_error(null_mut(), 100) }, needed);
    // Another thread has its own (empty) last error.
    std::thread::spawn(|| {
        let mut buf = [0x55u8; 4];
        // SAFETY: 4 writable bytes.
        assert_eq!(unsafe { lf_last_error(buf.as_mut_ptr().cast(), 4) }, 0);
        assert_eq!(buf[0], 0);
    })
    .join()
    .unwrap();
}

#[test]
fn wrong_lengths_are_refused_and_leave_the_output_alone() {
    let rt = Rt::load();
    let mut out = [7.0f32; 6];
    assert_eq!(
        rt.apply(0, &DIRECT[..5], &mut out),
        LfStatus::BadLength as i32
    );
    assert_eq!(
        last_error(),
        "lf_runtime_apply: direct_rgb holds 5 floats but this bundle needs 6 (3 per texel)"
    );
    assert_eq!(out, [7.0; 6]);
    let mut long = [7.0f32; 9];
    assert_eq!(rt.apply(0, &DIRECT, &mut long), LfStatus::BadLength as i32);
    assert!(last_error().contains("out_rgb holds 9 floats"));
    assert_eq!(rt.apply(0, &DIRECT, &mut []), LfStatus::BadLength as i32);
    assert_eq!(rt.direct(&[], &mut long[..3]), LfStatus::BadLength as i32);
    assert_eq!(long, [7.0; 9]);
}

#[test]
fn null_pointers_give_a_status_not_a_crash() {
    let rt = Rt::load();
    let mut out = [7.0f32; 6];
    let null_pointer = LfStatus::NullPointer as i32;
    let light = LfPointLight {
        position: [0.0, 1.0, 0.0],
        intensity: [1.0; 3],
    };
    // SAFETY: every pointer is NULL, live, or paired with a zero length.
    unsafe {
        assert_eq!(
            lf_runtime_apply(null_mut(), 0, DIRECT.as_ptr(), 6, out.as_mut_ptr(), 6),
            null_pointer
        );
        assert_eq!(last_error(), "lf_runtime_apply: rt is NULL");
        assert_eq!(
            lf_runtime_apply(rt.0, 0, null(), 6, out.as_mut_ptr(), 6),
            null_pointer
        );
        assert_eq!(last_error(), "lf_runtime_apply: direct_rgb is NULL");
        assert_eq!(
            lf_runtime_apply(rt.0, 0, DIRECT.as_ptr(), 6, null_mut(), 6),
            null_pointer
        );
        assert_eq!(last_error(), "lf_runtime_apply: out_rgb is NULL");
        assert_eq!(
            lf_runtime_direct_from_point_lights(null(), &light, 1, out.as_mut_ptr(), 6),
            null_pointer
        );
        assert_eq!(
            lf_runtime_direct_from_point_lights(rt.0, null(), 1, out.as_mut_ptr(), 6),
            null_pointer
        );
        assert_eq!(
            last_error(),
            "lf_runtime_direct_from_point_lights: lights is NULL"
        );
        assert_eq!(
            lf_runtime_direct_from_point_lights(rt.0, &light, 1, null_mut(), 6),
            null_pointer
        );
        assert_eq!(lf_runtime_texel_count(null()), 0);
        assert!(!lf_runtime_has_drt(null()));
        assert!(!lf_runtime_has_full(null()));
        lf_runtime_free(null_mut());
    }
    assert_eq!(out, [7.0; 6]);
}

#[test]
fn unknown_methods_and_missing_operators_are_refused() {
    let rt = Rt::load();
    let mut out = [7.0f32; 6];
    for bad in [-1, 3, i32::MAX] {
        assert_eq!(rt.apply(bad, &DIRECT, &mut out), LfStatus::BadMethod as i32);
    }
    assert_eq!(
        last_error(),
        format!(
            "lf_runtime_apply: unknown method {}: use LF_METHOD_MRT, LF_METHOD_DRT or LF_METHOD_FULL",
            i32::MAX
        )
    );
    let missing = LfStatus::MissingOperator as i32;
    assert_eq!(rt.apply(LfMethod::Drt as i32, &DIRECT, &mut out), missing);
    assert_eq!(
        last_error(),
        "lf_runtime_apply: this bundle has no DRT operators; bake a scene with clutter"
    );
    assert_eq!(rt.apply(LfMethod::Full as i32, &DIRECT, &mut out), missing);
    assert!(last_error().contains("no dense operator"));
    assert_eq!(out, [7.0; 6]);
    // The runtime still works after every refusal.
    assert_eq!(rt.apply(LfMethod::Mrt as i32, &DIRECT, &mut out), OK);
    assert_eq!(out, MRT);
}

#[test]
fn invalid_lights_are_refused() {
    let rt = Rt::load();
    let good = LfPointLight {
        position: [0.0, 1.0, 0.0],
        intensity: [1.0; 3],
    };
    let mut out = [7.0f32; 6];
    let cases = [
        ([f32::NAN, 1.0, 0.0], [1.0; 3], "position is not finite"),
        (
            [0.0, f32::INFINITY, 0.0],
            [1.0; 3],
            "position is not finite",
        ),
        (
            [0.0, 1.0, 0.0],
            [1.0, -0.5, 1.0],
            "intensity must be finite and non-negative",
        ),
        (
            [0.0, 1.0, 0.0],
            [1.0, 1.0, f32::INFINITY],
            "intensity must be finite and non-negative",
        ),
    ];
    for (position, intensity, reason) in cases {
        let bad = LfPointLight {
            position,
            intensity,
        };
        assert_eq!(
            rt.direct(&[good, bad], &mut out),
            LfStatus::InvalidLight as i32
        );
        assert_eq!(
            last_error(),
            format!("lf_runtime_direct_from_point_lights: lights[1]: {reason}")
        );
    }
    assert_eq!(out, [7.0; 6]);
}

/// All bounces of the two-texel operator in f64: `x_{k+1} = ρ ⊙ mean(x_k)` summed.
fn all_bounces(direct: &[f32; 6]) -> [f64; 6] {
    let rho = [0.5, 0.5, 0.5, 0.25, 0.5, 1.0];
    let mut x: Vec<f64> = direct.iter().map(|&v| v as f64).collect();
    let mut sum = [0.0; 6];
    for _ in 0..200 {
        let next: Vec<f64> = (0..6)
            .map(|i| rho[i] * (x[i % 3] + x[3 + i % 3]) / 2.0)
            .collect();
        for i in 0..6 {
            sum[i] += next[i];
        }
        x = next;
    }
    sum
}

#[test]
fn a_new_runtime_sums_all_bounces_and_says_how_many() {
    let rt = Rt::load_default();
    // SAFETY: live runtime.
    assert_eq!(unsafe { lf_runtime_last_bounces(rt.0) }, 0);
    // SAFETY: live runtime.
    assert_eq!(unsafe { lf_runtime_last_remaining(rt.0) }, 0.0);
    let mut out = [f32::NAN; 6];
    assert_eq!(rt.apply(LfMethod::Mrt as i32, &DIRECT, &mut out), OK);
    let want = all_bounces(&DIRECT);
    for (o, w) in out.iter().zip(want) {
        // The default tolerance leaves about 1e-3 of the light out.
        assert!((*o as f64 - w).abs() <= 3e-3 * w, "{o} vs {w}");
    }
    // SAFETY: live runtime.
    let bounces = unsafe { lf_runtime_last_bounces(rt.0) };
    // SAFETY: live runtime.
    let remaining = unsafe { lf_runtime_last_remaining(rt.0) };
    assert!((0.0..=1e-3).contains(&remaining), "{remaining}");
    // GMRES: the two-texel operator's Krylov space has two dimensions, so two applications
    // (the first bounce and one iteration) or three solve it.
    assert!((2..60).contains(&bounces), "{bounces}");
    // A tighter tolerance: at least as many applications, closer.
    // SAFETY: live runtime.
    assert_eq!(
        unsafe { lf_runtime_set_bounces(rt.0, LfBounces::Converged as i32, 1e-6) },
        OK
    );
    assert_eq!(rt.apply(LfMethod::Mrt as i32, &DIRECT, &mut out), OK);
    for (o, w) in out.iter().zip(want) {
        assert!((*o as f64 - w).abs() <= 1e-5 * w, "{o} vs {w}");
    }
    // SAFETY: live runtime.
    assert!(unsafe { lf_runtime_last_bounces(rt.0) } >= bounces);
    // SAFETY: live runtime.
    let remaining = unsafe { lf_runtime_last_remaining(rt.0) };
    assert!((0.0..=1e-6).contains(&remaining), "{remaining}");
    assert_eq!(unsafe { lf_runtime_last_bounces(null()) }, 0);
    assert_eq!(unsafe { lf_runtime_last_remaining(null()) }, 0.0);
}

#[test]
fn feedback_reaches_all_bounces_one_application_per_call() {
    let rt = Rt::load_default();
    // SAFETY: live runtime.
    assert_eq!(
        unsafe { lf_runtime_set_bounces(rt.0, LfBounces::Feedback as i32, 0.0) },
        OK
    );
    let mut out = [0.0f32; 6];
    assert_eq!(rt.apply(LfMethod::Mrt as i32, &DIRECT, &mut out), OK);
    assert_eq!(out, MRT, "the first call is one bounce");
    for _ in 0..100 {
        assert_eq!(rt.apply(LfMethod::Mrt as i32, &DIRECT, &mut out), OK);
        // SAFETY: live runtime.
        assert_eq!(unsafe { lf_runtime_last_bounces(rt.0) }, 1);
    }
    for (o, w) in out.iter().zip(all_bounces(&DIRECT)) {
        assert!((*o as f64 - w).abs() <= 1e-5 * w, "{o} vs {w}");
    }
}

#[test]
fn warm_starts_from_the_last_answer_one_application_while_light_holds_still() {
    let rt = Rt::load_default();
    // SAFETY: live runtime.
    assert_eq!(
        unsafe { lf_runtime_set_bounces(rt.0, LfBounces::Warm as i32, 1e-4) },
        OK
    );
    let want = all_bounces(&DIRECT);
    let mut out = [0.0f32; 6];
    assert_eq!(rt.apply(LfMethod::Mrt as i32, &DIRECT, &mut out), OK);
    // SAFETY: live runtime.
    let cold = unsafe { lf_runtime_last_bounces(rt.0) };
    assert!(cold >= 2, "the first call solves cold: {cold}");
    for call in 0..10 {
        assert_eq!(rt.apply(LfMethod::Mrt as i32, &DIRECT, &mut out), OK);
        // SAFETY: live runtime.
        let bounces = unsafe { lf_runtime_last_bounces(rt.0) };
        assert!(
            bounces <= if call == 0 { 3 } else { 1 },
            "{call}: {bounces}"
        );
        for (o, w) in out.iter().zip(want) {
            assert!((*o as f64 - w).abs() <= 1e-3 * w, "{o} vs {w}");
        }
    }
    // Light that doubles: still all bounces of the new light.
    let brighter = DIRECT.map(|v| v * 2.0);
    assert_eq!(rt.apply(LfMethod::Mrt as i32, &brighter, &mut out), OK);
    for (o, w) in out.iter().zip(all_bounces(&brighter)) {
        assert!((*o as f64 - w).abs() <= 1e-3 * w, "{o} vs {w}");
    }
}

#[test]
fn unknown_bounce_modes_and_tolerances_are_refused() {
    let rt = Rt::load();
    for (mode, tolerance) in [
        (4, 0.0f32),
        (-1, 0.0),
        (1, 1.0),
        (1, -0.5),
        (1, f32::NAN),
        (3, 2.0),
    ] {
        // SAFETY: live runtime.
        let status = unsafe { lf_runtime_set_bounces(rt.0, mode, tolerance) };
        assert_eq!(status, LfStatus::BadBounces as i32, "{mode} {tolerance}");
        assert!(last_error().starts_with("lf_runtime_set_bounces: "));
    }
    // SAFETY: NULL is refused, not dereferenced.
    let status = unsafe { lf_runtime_set_bounces(null_mut(), 0, 0.0) };
    assert_eq!(status, LfStatus::NullPointer as i32);
    // The mode is unchanged by the refusals: still one bounce.
    let mut out = [0.0f32; 6];
    assert_eq!(rt.apply(LfMethod::Mrt as i32, &DIRECT, &mut out), OK);
    assert_eq!(out, MRT);
}

impl Rt {
    fn apply_delta(&self, method: i32, delta: &[f32], indirect: &mut [f32]) -> i32 {
        // SAFETY: live runtime; the slices are live for the call and do not overlap.
        unsafe {
            lf_runtime_apply_delta(
                self.0,
                method,
                delta.as_ptr(),
                delta.len(),
                indirect.as_mut_ptr(),
                indirect.len(),
            )
        }
    }
}

#[test]
fn apply_delta_adds_the_indirect_light_of_the_change() {
    let mrt = LfMethod::Mrt as i32;
    let new_direct = [2.0f32, 2.0, 3.0, 3.0, 4.0, 9.0];
    let delta: Vec<f32> = new_direct.iter().zip(&DIRECT).map(|(a, b)| a - b).collect();
    for (mode, tolerance) in [(LfBounces::One, 0.0), (LfBounces::Converged, 1e-6)] {
        let rt = Rt::load();
        // SAFETY: live runtime.
        assert_eq!(
            unsafe { lf_runtime_set_bounces(rt.0, mode as i32, tolerance) },
            OK
        );
        let mut indirect = [0.0f32; 6];
        assert_eq!(rt.apply(mrt, &DIRECT, &mut indirect), OK);
        let mut want = [0.0f32; 6];
        assert_eq!(rt.apply(mrt, &new_direct, &mut want), OK);
        assert_eq!(rt.apply_delta(mrt, &delta, &mut indirect), OK);
        for (a, b) in indirect.iter().zip(&want) {
            assert!(
                (a - b).abs() <= 1e-5 * b.abs(),
                "{mode:?}: {indirect:?} vs {want:?}"
            );
        }
        // SAFETY: live runtime.
        assert!(unsafe { lf_runtime_last_bounces(rt.0) } >= 1);
    }
    // One bounce on this bundle is exact in f32: 0 + the change's light is MRT of it.
    let rt = Rt::load();
    let mut indirect = [0.0f32; 6];
    assert_eq!(rt.apply_delta(mrt, &DIRECT, &mut indirect), OK);
    assert_eq!(indirect, MRT);
}

impl Rt {
    fn apply_delta_in_spans(
        &self,
        method: i32,
        delta: &[f32],
        spans: &[LfTexelSpan],
        indirect: &mut [f32],
    ) -> i32 {
        // SAFETY: live runtime; the slices are live for the call and do not overlap.
        unsafe {
            lf_runtime_apply_delta_in_spans(
                self.0,
                method,
                delta.as_ptr(),
                delta.len(),
                spans.as_ptr(),
                spans.len(),
                indirect.as_mut_ptr(),
                indirect.len(),
            )
        }
    }
}

/// Relighting by a change named by its spans gives what `lf_runtime_apply_delta` gives with
/// that change (MRT and DRT, one bounce and all), reads the change on its spans only (NaN
/// elsewhere is never seen), clears its last call's spans before the next, and refuses a
/// span outside the layout leaving the light alone.
#[test]
fn apply_delta_in_spans_is_apply_delta_on_the_spans() {
    let mut rng = Lcg(0x5a7a_2026);
    let mut bundle = drt_bundle(&mut rng, false, true, false);
    // Dim albedo, so the random operators' bounces converge.
    for a in &mut bundle.layout.albedo {
        *a = a.map(|x| x * 0.2);
    }
    let bytes = bundle.encode();
    let load = || {
        // SAFETY: `bytes` is live for the call.
        let rt = unsafe { lf_runtime_new(bytes.as_ptr(), bytes.len()) };
        assert!(!rt.is_null(), "DRT test bundle loads: {}", last_error());
        Rt(rt)
    };
    let n = 17;
    let span = |start: u32, end: u32| LfTexelSpan {
        start,
        end,
        in_sight: 0,
    };
    // Changes one after another: block a's texels, then the lamp's and block b's.
    let steps = [vec![span(1, 3)], vec![span(14, 17), span(5, 9)]];
    let modes = [
        (LfBounces::One, 0.0),
        (LfBounces::Converged, 1e-6),
        (LfBounces::Feedback, 1e-3),
    ];
    for (mode, tolerance) in modes {
        for method in [LfMethod::Mrt as i32, LfMethod::Drt as i32] {
            let (whole, by_spans) = (load(), load());
            for rt in [&whole, &by_spans] {
                // SAFETY: live runtime.
                let set = unsafe { lf_runtime_set_bounces(rt.0, mode as i32, tolerance) };
                assert_eq!(set, OK);
            }
            let direct: Vec<f32> = (0..3 * n).map(|_| rng.range(0.1, 1.0)).collect();
            let mut a = vec![0.0f32; 3 * n];
            // Feedback by the change goes on from all bounces (a game's answer at load),
            // without an apply on the runtimes relighting (their light is then what their
            // feedback adds).
            let all_bounces = load();
            let start = if mode == LfBounces::Feedback {
                // SAFETY: live runtime.
                let set = unsafe {
                    lf_runtime_set_bounces(all_bounces.0, LfBounces::Converged as i32, 1e-6)
                };
                assert_eq!(set, OK);
                &all_bounces
            } else {
                &whole
            };
            assert_eq!(
                start.apply(method, &direct, &mut a),
                OK,
                "{mode:?} method {method}: {}",
                last_error()
            );
            let mut b = a.clone();
            let mut light = direct.clone();
            for spans in &steps {
                let mut delta = vec![0.0f32; 3 * n];
                let mut outside = vec![f32::NAN; 3 * n];
                for s in spans {
                    for k in 3 * s.start as usize..3 * s.end as usize {
                        delta[k] = rng.range(-0.3, 0.5);
                        outside[k] = delta[k];
                    }
                }
                assert_eq!(whole.apply_delta(method, &delta, &mut a), OK);
                assert_eq!(
                    by_spans.apply_delta_in_spans(method, &outside, spans, &mut b),
                    OK,
                    "{}",
                    last_error()
                );
                // Equal as values (a zero's sign may differ).
                assert_eq!(a, b, "{mode:?} method {method} spans {spans:?}");
                assert!(b.iter().all(|v| v.is_finite()));
                for (l, d) in light.iter_mut().zip(&delta) {
                    *l += d;
                }
            }
            if mode != LfBounces::Feedback {
                continue;
            }
            // Feedback settles: calls with no span until nothing is due, then all bounces of
            // the last light within the tolerance (×2; L1, relative).
            let zero = vec![0.0f32; 3 * n];
            let mut calls = 0;
            // SAFETY: live runtime.
            let lag = unsafe { lf_runtime_last_remaining(by_spans.0) };
            assert!(lag > 0.0, "method {method}: light is still to arrive");
            // SAFETY: live runtime.
            while unsafe { lf_runtime_feedback_due(by_spans.0) } > 0 {
                calls += 1;
                assert!(calls < 100, "method {method}: still due after 100 calls");
                assert_eq!(
                    by_spans.apply_delta_in_spans(method, &zero, &[], &mut b),
                    OK
                );
            }
            assert!(calls > 0, "method {method}: nothing was due");
            // Settled: what is left is within the tolerance (the default, 1e-3), by the
            // runtime's estimate.
            // SAFETY: live runtime.
            let left = unsafe { lf_runtime_last_remaining(by_spans.0) };
            assert!(
                left <= 1e-3 && left < lag,
                "method {method}: {left} left of {lag}"
            );
            let all = load();
            let mut want = vec![0.0f32; 3 * n];
            // SAFETY: live runtime.
            let set = unsafe { lf_runtime_set_bounces(all.0, LfBounces::Converged as i32, 1e-6) };
            assert_eq!(set, OK);
            assert_eq!(all.apply(method, &light, &mut want), OK);
            let diff: f64 = b.iter().zip(&want).map(|(x, y)| (x - y).abs() as f64).sum();
            let norm: f64 = want.iter().map(|y| y.abs() as f64).sum();
            assert!(
                diff <= 2e-3 * norm,
                "method {method}: {} after {calls} calls",
                diff / norm
            );
        }
    }
    let rt = load();
    let mut indirect = vec![0.5f32; 3 * n];
    let bad = [span(2, 4), span(16, 18)];
    assert_eq!(
        rt.apply_delta_in_spans(0, &vec![1.0; 3 * n], &bad, &mut indirect),
        LfStatus::BadIndex as i32
    );
    assert!(last_error().contains("spans[1]"), "{}", last_error());
    assert_eq!(indirect, vec![0.5f32; 3 * n]);
}

/// `lf_runtime_set_feedback_budget`: `SIZE_MAX` shoots every due unit, 0 one a call, so the
/// same light settles in more calls to the same tolerance; NULL is refused.
#[test]
fn the_feedback_budget_is_set_through_c() {
    let mut rng = Lcg(0x0b0d_9e7);
    let mut bundle = drt_bundle(&mut rng, false, true, false);
    for a in &mut bundle.layout.albedo {
        *a = a.map(|x| x * 0.2);
    }
    let bytes = bundle.encode();
    let n = bundle.layout.n_texels();
    let direct: Vec<f32> = (0..3 * n).map(|_| rng.range(0.1, 1.0)).collect();
    let drt = LfMethod::Drt as i32;
    let mut settled = Vec::new();
    for budget in [usize::MAX, 0] {
        // SAFETY: `bytes` is live for the call.
        let rt = Rt(unsafe { lf_runtime_new(bytes.as_ptr(), bytes.len()) });
        // SAFETY: live runtime.
        unsafe {
            assert_eq!(
                lf_runtime_set_bounces(rt.0, LfBounces::Feedback as i32, 1e-3),
                OK
            );
            assert_eq!(lf_runtime_set_feedback_budget(rt.0, budget), OK);
        }
        // From darkness: the first call's change is all the light.
        let mut light = vec![0.0f32; 3 * n];
        assert_eq!(rt.apply_delta(drt, &direct, &mut light), OK);
        let zero = vec![0.0f32; 3 * n];
        let mut calls = 0;
        // SAFETY: live runtime.
        while unsafe { lf_runtime_feedback_due(rt.0) } > 0 {
            calls += 1;
            assert!(calls < 1000, "budget {budget}: still due after 1000 calls");
            assert_eq!(rt.apply_delta(drt, &zero, &mut light), OK);
        }
        settled.push((calls, light));
    }
    // SAFETY: live runtime for the reference.
    let all = Rt(unsafe { lf_runtime_new(bytes.as_ptr(), bytes.len()) });
    let set = unsafe { lf_runtime_set_bounces(all.0, LfBounces::Converged as i32, 1e-6) };
    assert_eq!(set, OK);
    let mut want = vec![0.0f32; 3 * n];
    assert_eq!(all.apply(drt, &direct, &mut want), OK);
    let norm: f64 = want.iter().map(|y| y.abs() as f64).sum();
    for (calls, light) in &settled {
        let diff: f64 = light
            .iter()
            .zip(&want)
            .map(|(x, y)| (x - y).abs() as f64)
            .sum();
        assert!(diff <= 2e-3 * norm, "{} after {calls} calls", diff / norm);
    }
    assert!(
        settled[1].0 > settled[0].0,
        "one unit a call: {} calls, every due unit: {}",
        settled[1].0,
        settled[0].0
    );
    // SAFETY: NULL is refused, never read.
    assert_eq!(
        unsafe { lf_runtime_set_feedback_budget(null_mut(), 0) },
        LfStatus::NullPointer as i32
    );
}

#[test]
fn apply_delta_refuses_feedback_of_full_bad_lengths_and_nulls_and_leaves_the_light_alone() {
    let rt = Rt::load();
    let mrt = LfMethod::Mrt as i32;
    let mut indirect = MRT;
    // SAFETY: live runtime.
    assert_eq!(
        unsafe { lf_runtime_set_bounces(rt.0, LfBounces::Feedback as i32, 0.0) },
        OK
    );
    assert_eq!(
        rt.apply_delta(LfMethod::Full as i32, &DIRECT, &mut indirect),
        LfStatus::BadBounces as i32
    );
    assert!(last_error().contains("Feedback"), "{}", last_error());
    assert_eq!(indirect, MRT);
    let rt = Rt::load();
    assert_eq!(
        rt.apply_delta(mrt, &DIRECT[..5], &mut indirect),
        LfStatus::BadLength as i32
    );
    assert_eq!(
        rt.apply_delta(mrt, &DIRECT, &mut indirect[..5]),
        LfStatus::BadLength as i32
    );
    assert_eq!(
        rt.apply_delta(99, &DIRECT, &mut indirect),
        LfStatus::BadMethod as i32
    );
    // SAFETY: NULL runtime and NULL buffers with non-zero lengths are refused, never read.
    unsafe {
        assert_eq!(
            lf_runtime_apply_delta(
                null_mut(),
                mrt,
                DIRECT.as_ptr(),
                6,
                indirect.as_mut_ptr(),
                6
            ),
            LfStatus::NullPointer as i32
        );
        assert_eq!(
            lf_runtime_apply_delta(rt.0, mrt, null(), 6, indirect.as_mut_ptr(), 6),
            LfStatus::NullPointer as i32
        );
        assert_eq!(
            lf_runtime_apply_delta(rt.0, mrt, DIRECT.as_ptr(), 6, null_mut(), 6),
            LfStatus::NullPointer as i32
        );
    }
    assert_eq!(indirect, MRT);
}

/// The one-light entry points on the two-texel bundle (no rooms section: a light reaches
/// everything): the spans, the count protocol, direct light written on a span only, and every
/// error path.
#[test]
fn light_reach_and_direct_in_spans() {
    let rt = Rt::load();
    let p = [0.5f32, 1.0, 0.25];
    let mut count = 99usize;
    // SAFETY: live runtime; every buffer is live for its call with the length passed; NULLs
    // are refused, never read.
    unsafe {
        assert_eq!(
            lf_runtime_light_reach(rt.0, p.as_ptr(), null_mut(), 0, &mut count),
            LfStatus::BadLength as i32
        );
        assert_eq!(count, 1);
        assert!(
            last_error().contains("out_spans holds 0 but 1 are needed"),
            "{}",
            last_error()
        );
        let mut spans = [LfTexelSpan::default(); 2];
        assert_eq!(
            lf_runtime_light_reach(rt.0, p.as_ptr(), spans.as_mut_ptr(), 2, &mut count),
            OK
        );
        assert_eq!(count, 1);
        assert_eq!(
            spans[0],
            LfTexelSpan {
                start: 0,
                end: 2,
                in_sight: 0
            }
        );
        let refused = |status: i32, what: &str| {
            assert_eq!(status, LfStatus::NullPointer as i32, "{what}");
            let message = last_error();
            assert!(message.contains(&format!("{what} is NULL")), "{message}");
        };
        let out = spans.as_mut_ptr();
        refused(
            lf_runtime_light_reach(null_mut(), p.as_ptr(), out, 2, &mut count),
            "rt",
        );
        refused(
            lf_runtime_light_reach(rt.0, null(), out, 2, &mut count),
            "position",
        );
        refused(
            lf_runtime_light_reach(rt.0, p.as_ptr(), out, 2, null_mut()),
            "out_count",
        );
        refused(
            lf_runtime_light_reach(rt.0, p.as_ptr(), null_mut(), 2, &mut count),
            "out_spans",
        );
        let nan = [f32::NAN, 1.0, 0.0];
        assert_eq!(
            lf_runtime_light_reach(rt.0, nan.as_ptr(), spans.as_mut_ptr(), 2, &mut count),
            LfStatus::InvalidLight as i32
        );

        // Direct light on texel 1 only: texel 0 keeps its value, texel 1 gets what lighting
        // both gives.
        let light = LfPointLight {
            position: p,
            intensity: [2.0, 1.0, 0.5],
        };
        let everything = [LfTexelSpan {
            start: 0,
            end: 2,
            in_sight: 0,
        }];
        let second = [LfTexelSpan {
            start: 1,
            end: 2,
            in_sight: 0,
        }];
        let mut whole = [0.0f32; 6];
        let mut part = [-1.0f32; 6];
        let call = |spans: &[LfTexelSpan], out: &mut [f32]| {
            lf_runtime_direct_in_spans(
                rt.0,
                &light,
                1,
                spans.as_ptr(),
                spans.len(),
                out.as_mut_ptr(),
                out.len(),
            )
        };
        assert_eq!(call(&everything, &mut whole), OK);
        assert!(whole.iter().all(|v| *v > 0.0), "{whole:?}");
        assert_eq!(call(&second, &mut part), OK);
        assert_eq!(part[..3], [-1.0; 3]);
        assert_eq!(part[3..], whole[3..]);
        // A span past the layout, or reversed: BAD_INDEX, output untouched.
        for bad in [(0, 3), (2, 1)] {
            let span = [LfTexelSpan {
                start: bad.0,
                end: bad.1,
                in_sight: 0,
            }];
            let mut out = [5.0f32; 6];
            assert_eq!(call(&span, &mut out), LfStatus::BadIndex as i32);
            assert!(last_error().contains("spans[0]"), "{}", last_error());
            assert_eq!(out, [5.0; 6]);
        }
        assert_eq!(
            call(&everything, &mut whole[..5]),
            LfStatus::BadLength as i32
        );
        assert_eq!(
            lf_runtime_direct_in_spans(rt.0, &light, 1, null(), 1, whole.as_mut_ptr(), 6),
            LfStatus::NullPointer as i32
        );
    }
}

/// `lf_runtime_light_direct` on the two-texel bundle (no rooms: the light reaches every
/// texel): the spans of `lf_runtime_light_reach`, the direct light `lf_runtime_direct_in_spans`
/// gives on them bit for bit, the count protocol, and nothing written on any error.
#[test]
fn light_direct_is_light_reach_then_direct_in_spans() {
    let rt = Rt::load();
    let light = LfPointLight {
        position: [0.5, 1.0, 0.25],
        intensity: [2.0, 1.0, 0.5],
    };
    let mut count = 99usize;
    let mut spans = [LfTexelSpan::default(); 2];
    let mut out = [-1.0f32; 6];
    // SAFETY: live runtime; every buffer is live for its call with the length passed; NULLs
    // are refused, never read.
    unsafe {
        // Too few spans: the count, and nothing written.
        assert_eq!(
            lf_runtime_light_direct(rt.0, &light, null_mut(), 0, &mut count, out.as_mut_ptr(), 6),
            LfStatus::BadLength as i32
        );
        assert_eq!(count, 1);
        assert_eq!(out, [-1.0; 6]);
        assert_eq!(
            lf_runtime_light_direct(
                rt.0,
                &light,
                spans.as_mut_ptr(),
                2,
                &mut count,
                out.as_mut_ptr(),
                6
            ),
            OK
        );
        assert_eq!(count, 1);
        let mut reach = [LfTexelSpan::default(); 2];
        let mut n = 0usize;
        assert_eq!(
            lf_runtime_light_reach(rt.0, light.position.as_ptr(), reach.as_mut_ptr(), 2, &mut n),
            OK
        );
        assert_eq!(spans[..count], reach[..n]);
        let mut want = [-1.0f32; 6];
        assert_eq!(
            lf_runtime_direct_in_spans(rt.0, &light, 1, reach.as_ptr(), n, want.as_mut_ptr(), 6),
            OK
        );
        assert_eq!(out.map(f32::to_bits), want.map(f32::to_bits));
        assert!(out.iter().all(|v| *v > 0.0), "{out:?}");
        // Errors: nothing written.
        let mut untouched = [7.0f32; 6];
        let bad = LfPointLight {
            position: [f32::NAN, 0.0, 0.0],
            ..light
        };
        let check = |status: i32, message: &str| {
            assert_ne!(status, OK, "{message}");
            assert!(
                last_error().contains(message),
                "{message}: {}",
                last_error()
            );
        };
        let out = untouched.as_mut_ptr();
        let sp = spans.as_mut_ptr();
        check(
            lf_runtime_light_direct(null_mut(), &light, sp, 2, &mut count, out, 6),
            "rt is NULL",
        );
        check(
            lf_runtime_light_direct(rt.0, null(), sp, 2, &mut count, out, 6),
            "light is NULL",
        );
        check(
            lf_runtime_light_direct(rt.0, &bad, sp, 2, &mut count, out, 6),
            "not finite",
        );
        check(
            lf_runtime_light_direct(rt.0, &light, sp, 2, &mut count, out, 5),
            "out_rgb",
        );
        check(
            lf_runtime_light_direct(rt.0, &light, null_mut(), 2, &mut count, out, 6),
            "out_spans is NULL",
        );
        check(
            lf_runtime_light_direct(rt.0, &light, sp, 2, null_mut(), out, 6),
            "out_count is NULL",
        );
        assert_eq!(untouched, [7.0; 6]);
    }
}
