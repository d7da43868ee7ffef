//! Every entry point called as C calls it, on a hand-built two-texel bundle whose MRT output is
//! known exactly: results, then every error path (garbage bytes, wrong lengths, NULL
//! pointers, unknown methods, missing operators, invalid lights) and the last-error contract;
//! then the bounce modes (all bounces by default, one, feedback) against the geometric series
//! of the same operator.

use std::ffi::CStr;
use std::ptr::{null, null_mut};

use lightfarm::*;
use lightfarm_client::{direct_from_point_lights_averaged, Light, Occluders};
use lightfarm_proto::bundle::{Bundle, Layout, Matrix, SurfaceInfo};
use lightfarm_proto::lights::LightKind;
use lightfarm_proto::testing::one_block_bundle;

const OK: i32 = LfStatus::Ok as i32;

/// One block of two floor texels (albedo grey and blue-ish) whose only operator averages them:
/// `U_b = [1, 1]ᵀ`, `T_d→b = [½, ½]`, so MRT gives `ρ_t · (l_0 + l_1) / 2` at each texel.
fn two_texel_bundle() -> Vec<u8> {
    let layout = Layout {
        scene_name: "two texels".into(),
        surfaces: vec![SurfaceInfo {
            name: "block:room/-y".into(),
            texel_offset: 0,
            texel_count: 2,
        }],
        positions: vec![[0.25, 0.0, 0.25], [0.75, 0.0, 0.25]],
        normals: vec![[0.0, 1.0, 0.0]; 2],
        albedo: vec![[0.5, 0.5, 0.5], [0.25, 0.5, 1.0]],
        texel_size: vec![[0.5, 0.5]; 2],
        rects: vec![],
        triangles: vec![],
    };
    let u_b = Matrix {
        rows: 2,
        cols: 1,
        data: vec![1.0, 1.0],
    };
    let t_db = Matrix {
        rows: 1,
        cols: 2,
        data: vec![0.5, 0.5],
    };
    one_block_bundle(layout, "room", "pair", u_b, t_db).encode()
}

/// Owns a runtime for the length of a test.
struct Rt(*mut LfRuntime);

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

impl Drop for Rt {
    fn drop(&mut self) {
        // SAFETY: from lf_runtime_new, freed once.
        unsafe { lf_runtime_free(self.0) }
    }
}

/// This thread's last error through `lf_last_error`, checking its size contract.
fn last_error() -> String {
    // SAFETY: NULL with cap 0 asks for the size only.
    let needed = unsafe { lf_last_error(null_mut(), 0) };
    let mut buf = vec![0x55u8; needed.max(1)];
    // SAFETY: `buf.len()` writable bytes.
    let again = unsafe { lf_last_error(buf.as_mut_ptr().cast(), buf.len()) };
    assert_eq!(again, needed);
    let text = CStr::from_bytes_with_nul(&buf).expect("NUL exactly at the end");
    assert_eq!(text.to_bytes().len() + 1, needed.max(1));
    text.to_str().unwrap().to_owned()
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
    let mut out = [f32::NAN; 6];
    assert_eq!(rt.apply(LfMethod::Mrt as i32, &DIRECT, &mut out), OK);
    let want = all_bounces(&DIRECT);
    for (o, w) in out.iter().zip(want) {
        // The default tolerance leaves about 1e-3 of the light out.
        assert!((*o as f64 - w).abs() <= 3e-3 * w, "{o} vs {w}");
    }
    // SAFETY: live runtime.
    let bounces = unsafe { lf_runtime_last_bounces(rt.0) };
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
    assert_eq!(unsafe { lf_runtime_last_bounces(null()) }, 0);
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
fn unknown_bounce_modes_and_tolerances_are_refused() {
    let rt = Rt::load();
    for (mode, tolerance) in [(3, 0.0f32), (-1, 0.0), (1, 1.0), (1, -0.5), (1, f32::NAN)] {
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
