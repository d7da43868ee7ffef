//! Every entry point called as C calls it, on a hand-built two-texel bundle whose MRT output is
//! known exactly: results, then every error path (garbage bytes, wrong lengths, NULL
//! pointers, unknown methods, missing operators, invalid lights) and the last-error contract;
//! then the bounce modes (all bounces by default, one, feedback) against the geometric series
//! of the same operator. Then the texel layout and atlas queries on a four-surface bundle
//! with a mesh atlas: exact values, every error path, and direct light an engine computes from
//! them applying like the client's. Last, the one-light entry points (reach spans, direct light
//! on spans) and their error paths.

use std::ffi::CStr;
use std::ptr::{null, null_mut};

use lightfarm::*;
use lightfarm_client::{direct_from_point_lights_averaged, Atlas, Light, Occluders};
use lightfarm_proto::bundle::{Bundle, Layout, Matrix, SurfaceAtlas, SurfaceInfo};
use lightfarm_proto::lights::LightKind;
use lightfarm_proto::testing::{drt_bundle, one_block_bundle, Lcg};

const OK: i32 = LfStatus::Ok as i32;

/// `testing::two_texel_bundle`: MRT gives `ρ_t · (l_0 + l_1) / 2` at each texel.
fn two_texel_bundle() -> Vec<u8> {
    lightfarm_proto::testing::two_texel_bundle().encode()
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

/// Four surfaces, 17 texels, every per-texel value distinct: a 2×2 floor and wall of block
/// `room`, a box (`clutter:crate`, six texels: two atlas tiles) and a mesh (`clutter:teapot`,
/// three slanted texels) with its own 2×2 lightmap image. One operator block holds them all.
fn layout_bundle() -> Bundle {
    let surfaces = [
        ("block:room/-y", 4u32),
        ("block:room/+x", 4),
        ("clutter:crate", 6),
        ("clutter:teapot", 3),
    ];
    let mut next = 0;
    let surfaces = surfaces
        .iter()
        .map(|&(name, texel_count)| {
            next += texel_count;
            SurfaceInfo {
                name: name.into(),
                texel_offset: next - texel_count,
                texel_count,
            }
        })
        .collect();
    let n = next as usize;
    let normal = |t: usize| match t {
        0..=3 => [0.0, 1.0, 0.0],
        4..=7 => [-1.0, 0.0, 0.0],
        8..=13 => [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]][t % 3],
        _ => [0.6, 0.8, 0.0],
    };
    let layout = Layout {
        scene_name: "layout".into(),
        surfaces,
        positions: (0..n)
            .map(|t| {
                let t = t as f32;
                [0.125 + 0.25 * t, 0.0625 * (t % 3.0), 2.0 - 0.0625 * t]
            })
            .collect(),
        normals: (0..n).map(normal).collect(),
        albedo: (0..n)
            .map(|t| {
                let t = t as f32;
                [0.03125 * (t + 1.0), 0.5, 0.875 - 0.03125 * t]
            })
            .collect(),
        texel_size: (0..n)
            .map(|t| [0.25 + 0.015625 * t as f32, 0.5 - 0.0078125 * t as f32])
            .collect(),
        rects: vec![],
        triangles: vec![],
    };
    let m = |rows: usize, cols: usize| Matrix {
        rows: rows as u32,
        cols: cols as u32,
        data: (0..rows * cols).map(|k| 0.02 + 0.001 * k as f32).collect(),
    };
    let mut bundle = one_block_bundle(layout, "room", "room", m(n, 2), m(2, n));
    bundle.surface_atlases = vec![SurfaceAtlas {
        surface: 3,
        width: 2,
        height: 2,
        texel_xy: vec![[0, 0], [1, 0], [1, 1]],
    }];
    bundle
}

/// A runtime of [`layout_bundle`], and the bundle as decoded.
fn load_layout() -> (Rt, Bundle) {
    let bytes = layout_bundle().encode();
    // SAFETY: `bytes` is live for the call.
    let rt = unsafe { lf_runtime_new(bytes.as_ptr(), bytes.len()) };
    assert!(!rt.is_null(), "layout bundle loads: {}", last_error());
    (Rt(rt), Bundle::decode(&bytes).unwrap())
}

/// The four per-texel float queries with their floats per texel.
type FloatQuery = unsafe extern "C" fn(*const LfRuntime, *mut f32, usize) -> i32;
const FLOAT_QUERIES: [(&str, FloatQuery, usize); 4] = [
    ("lf_runtime_texel_positions", lf_runtime_texel_positions, 3),
    ("lf_runtime_texel_normals", lf_runtime_texel_normals, 3),
    ("lf_runtime_texel_albedo", lf_runtime_texel_albedo, 3),
    ("lf_runtime_texel_sizes", lf_runtime_texel_sizes, 2),
];

/// A per-texel float query into a fresh buffer of `per_texel × texels` floats.
fn floats(rt: &Rt, query: FloatQuery, per_texel: usize) -> Vec<f32> {
    // SAFETY: live runtime.
    let n = per_texel * unsafe { lf_runtime_texel_count(rt.0) };
    let mut out = vec![f32::NAN; n];
    // SAFETY: live runtime; `n` writable floats.
    assert_eq!(unsafe { query(rt.0, out.as_mut_ptr(), n) }, OK);
    out
}

#[test]
fn texel_layout_is_the_bundles_exactly() {
    let (rt, bundle) = load_layout();
    let layout = &bundle.layout;
    // SAFETY: live runtime.
    assert_eq!(unsafe { lf_runtime_texel_count(rt.0) }, 17);
    let [positions, normals, albedo, sizes] =
        FLOAT_QUERIES.map(|(_, query, per_texel)| floats(&rt, query, per_texel));
    assert_eq!(positions, layout.positions.as_flattened());
    assert_eq!(normals, layout.normals.as_flattened());
    assert_eq!(albedo, layout.albedo.as_flattened());
    assert_eq!(sizes, layout.texel_size.as_flattened());
    // Spot checks against the fixture's formulas: texel 5 (the wall), texel 15 (the mesh).
    assert_eq!(&positions[15..18], &[1.375, 0.125, 1.6875]);
    assert_eq!(&normals[45..48], &[0.6, 0.8, 0.0]);
    assert_eq!(&albedo[15..18], &[0.1875, 0.5, 0.71875]);
    assert_eq!(&sizes[10..12], &[0.328125, 0.4609375]);
}

#[test]
fn atlas_placement_is_the_lightmap_files_atlas() {
    let (rt, bundle) = load_layout();
    let (mut width, mut height) = (0u32, 0u32);
    // SAFETY: live runtime; two writable integers.
    assert_eq!(
        unsafe { lf_runtime_atlas_size(rt.0, &mut width, &mut height) },
        OK
    );
    let mut xy = [u32::MAX; 34];
    // SAFETY: live runtime; 34 writable integers.
    assert_eq!(
        unsafe { lf_runtime_atlas_texels(rt.0, xy.as_mut_ptr(), xy.len()) },
        OK
    );
    let atlas = Atlas::from_layout_with(&bundle.layout, &bundle.surface_atlases);
    assert_eq!((width, height), (atlas.width, atlas.height));
    let want: Vec<u32> = atlas.texel_xy.iter().flat_map(|&(x, y)| [x, y]).collect();
    assert_eq!(xy.as_slice(), want);
    // By hand: 2×2 tiles one pixel apart on a 2×2 grid (floor, wall, the crate's two), the
    // teapot's own 2×2 image on the row below them.
    assert_eq!((width, height), (5, 8));
    let pairs: Vec<(u32, u32)> = xy.chunks(2).map(|p| (p[0], p[1])).collect();
    let by_surface: [&[(u32, u32)]; 4] = [
        &[(0, 0), (1, 0), (0, 1), (1, 1)],                 // floor: tile 0
        &[(3, 0), (4, 0), (3, 1), (4, 1)],                 // wall: tile 1
        &[(0, 3), (1, 3), (0, 4), (1, 4), (3, 3), (4, 3)], // crate: tiles 2, 3
        &[(0, 6), (1, 6), (1, 7)],                         // teapot: its own image
    ];
    assert_eq!(pairs, by_surface.concat());
}

#[test]
fn surfaces_name_their_texel_ranges() {
    let (rt, bundle) = load_layout();
    // SAFETY: live runtime.
    let count = unsafe { lf_runtime_surface_count(rt.0) };
    assert_eq!(count, 4);
    let mut got = Vec::new();
    for index in 0..count {
        let mut name = [0x55u8; 32];
        let (mut offset, mut texels) = (u32::MAX, u32::MAX);
        // SAFETY: live runtime; 32 writable bytes, two writable integers.
        let needed = unsafe {
            lf_runtime_surface(
                rt.0,
                index,
                name.as_mut_ptr().cast(),
                name.len(),
                &mut offset,
                &mut texels,
            )
        };
        let name = CStr::from_bytes_until_nul(&name).unwrap().to_str().unwrap();
        assert_eq!(needed, name.len() as i64 + 1);
        got.push((name.to_owned(), offset, texels));
    }
    assert_eq!(
        got,
        [
            ("block:room/-y".to_owned(), 0, 4),
            ("block:room/+x".to_owned(), 4, 4),
            ("clutter:crate".to_owned(), 8, 6),
            ("clutter:teapot".to_owned(), 14, 3),
        ]
    );
    let want: Vec<_> = bundle
        .layout
        .surfaces
        .iter()
        .map(|s| (s.name.clone(), s.texel_offset, s.texel_count))
        .collect();
    assert_eq!(got, want);
    // SAFETY: NULL runtime: no surfaces.
    assert_eq!(unsafe { lf_runtime_surface_count(null()) }, 0);
}

#[test]
fn surface_names_are_cut_to_the_buffer_and_report_their_size() {
    let (rt, _) = load_layout();
    // Size only: NULL buffer, zero capacity, no texel range wanted.
    // SAFETY: live runtime; nothing is written.
    let needed = unsafe { lf_runtime_surface(rt.0, 3, null_mut(), 0, null_mut(), null_mut()) };
    assert_eq!(needed, "clutter:teapot".len() as i64 + 1);
    // Too small: the first cap - 1 bytes and a NUL; the range is still written.
    let mut name = [0x55u8; 8];
    let mut offset = u32::MAX;
    // SAFETY: live runtime; 8 writable bytes, one writable integer.
    let got = unsafe {
        lf_runtime_surface(
            rt.0,
            3,
            name.as_mut_ptr().cast(),
            8,
            &mut offset,
            null_mut(),
        )
    };
    assert_eq!(got, 15);
    assert_eq!(&name, b"clutter\0");
    assert_eq!(offset, 14);
    // Exactly the size it asked for.
    let mut name = [0x55u8; 15];
    // SAFETY: live runtime; 15 writable bytes.
    let got = unsafe {
        lf_runtime_surface(
            rt.0,
            3,
            name.as_mut_ptr().cast(),
            15,
            null_mut(),
            null_mut(),
        )
    };
    assert_eq!(got, 15);
    assert_eq!(&name, b"clutter:teapot\0");
    // One byte: only the NUL.
    let mut one = [0x55u8; 1];
    // SAFETY: live runtime; 1 writable byte.
    let got =
        unsafe { lf_runtime_surface(rt.0, 0, one.as_mut_ptr().cast(), 1, null_mut(), null_mut()) };
    assert_eq!((got, one), (14, [0]));
}

#[test]
fn surface_errors_name_the_index_and_write_nothing() {
    let (rt, _) = load_layout();
    let mut name = [0x55u8; 32];
    let (mut offset, mut texels) = (7u32, 7u32);
    let mut call = |rt: *const LfRuntime, index: usize, name_ptr: *mut u8, cap: usize| {
        // SAFETY: NULL or live runtime; NULL or `cap` writable bytes; two writable integers.
        unsafe { lf_runtime_surface(rt, index, name_ptr.cast(), cap, &mut offset, &mut texels) }
    };
    let p = name.as_mut_ptr();
    for index in [4, 5, usize::MAX] {
        assert_eq!(call(rt.0, index, p, 32), LfStatus::BadIndex as i64);
        assert_eq!(
            last_error(),
            format!("lf_runtime_surface: surface index {index} is out of range: this bundle has 4 surfaces")
        );
    }
    assert_eq!(call(null(), 0, p, 32), LfStatus::NullPointer as i64);
    assert_eq!(last_error(), "lf_runtime_surface: rt is NULL");
    assert_eq!(call(rt.0, 0, null_mut(), 32), LfStatus::NullPointer as i64);
    assert_eq!(last_error(), "lf_runtime_surface: name is NULL");
    assert_eq!((offset, texels), (7, 7));
    assert_eq!(name, [0x55; 32]);
    assert_eq!(LfStatus::BadIndex as i32, -10);
}

#[test]
fn layout_queries_refuse_null_and_wrong_lengths_and_write_nothing() {
    let (rt, _) = load_layout();
    let mut buf = [7.0f32; 60];
    let p = buf.as_mut_ptr();
    for (function, query, per_texel) in FLOAT_QUERIES {
        let n = per_texel * 17;
        for len in [n - 1, n + 1, 0] {
            // SAFETY: live runtime; `len` <= 60 writable floats.
            assert_eq!(unsafe { query(rt.0, p, len) }, LfStatus::BadLength as i32);
            assert_eq!(
                last_error(),
                format!(
                    "{function}: out holds {len} floats but this bundle needs {n} ({per_texel} per texel)"
                )
            );
        }
        // SAFETY: NULL runtime / NULL output.
        unsafe {
            assert_eq!(query(null(), p, n), LfStatus::NullPointer as i32);
            assert_eq!(last_error(), format!("{function}: rt is NULL"));
            assert_eq!(query(rt.0, null_mut(), n), LfStatus::NullPointer as i32);
            assert_eq!(last_error(), format!("{function}: out is NULL"));
        }
    }
    assert_eq!(buf, [7.0; 60]);

    let mut xy = [7u32; 40];
    let q = xy.as_mut_ptr();
    let (mut width, mut height) = (7u32, 7u32);
    // SAFETY: NULL or live runtime; NULL or `len` <= 40 writable integers.
    unsafe {
        for len in [33, 35, 0] {
            assert_eq!(
                lf_runtime_atlas_texels(rt.0, q, len),
                LfStatus::BadLength as i32
            );
            assert_eq!(
                last_error(),
                format!("lf_runtime_atlas_texels: xy holds {len} integers but this bundle needs 34 (2 per texel)")
            );
        }
        assert_eq!(
            lf_runtime_atlas_texels(null(), q, 34),
            LfStatus::NullPointer as i32
        );
        assert_eq!(
            lf_runtime_atlas_texels(rt.0, null_mut(), 34),
            LfStatus::NullPointer as i32
        );
        assert_eq!(last_error(), "lf_runtime_atlas_texels: xy is NULL");
        assert_eq!(
            lf_runtime_atlas_size(null(), &mut width, &mut height),
            LfStatus::NullPointer as i32
        );
        assert_eq!(last_error(), "lf_runtime_atlas_size: rt is NULL");
        assert_eq!(
            lf_runtime_atlas_size(rt.0, null_mut(), &mut height),
            LfStatus::NullPointer as i32
        );
        assert_eq!(last_error(), "lf_runtime_atlas_size: width is NULL");
        assert_eq!(
            lf_runtime_atlas_size(rt.0, &mut width, null_mut()),
            LfStatus::NullPointer as i32
        );
        assert_eq!(last_error(), "lf_runtime_atlas_size: height is NULL");
    }
    assert_eq!((xy, width, height), ([7; 40], 7, 7));
}

/// What an engine does with the layout: direct light from point lights at each texel centre,
/// `ρ/π · Σ I · max(cosθ, 0) / r²`, in the client's operation order (f64, then f32), without
/// shadows (the engine has its own; the fixture has no occluders).
fn engine_direct(positions: &[f32], normals: &[f32], albedo: &[f32], lights: &[Light]) -> Vec<f32> {
    let mut direct = Vec::with_capacity(albedo.len());
    for ((x, n), rho) in positions
        .chunks(3)
        .zip(normals.chunks(3))
        .zip(albedo.chunks(3))
    {
        let mut irr = [0.0f64; 3];
        for light in lights {
            let to: Vec<f64> = (0..3).map(|k| light.position[k] - x[k] as f64).collect();
            let r2 = to[0] * to[0] + to[1] * to[1] + to[2] * to[2];
            let cos = (n[0] as f64 * to[0] + n[1] as f64 * to[1] + n[2] as f64 * to[2]) / r2.sqrt();
            if cos <= 0.0 {
                continue;
            }
            let g = cos / r2;
            for (e, i) in irr.iter_mut().zip(light.intensity) {
                *e += i * g;
            }
        }
        for c in 0..3 {
            direct.push((rho[c] as f64 * std::f64::consts::FRAC_1_PI * irr[c]) as f32);
        }
    }
    direct
}

#[test]
fn direct_light_from_the_c_layout_applies_like_the_clients() {
    let (rt, bundle) = load_layout();
    let lights = [
        Light {
            kind: LightKind::Point,
            position: [1.5, 2.0, 1.0],
            intensity: [3.0, 2.0, 1.0],
        },
        Light {
            kind: LightKind::Point,
            position: [-1.0, 0.5, 3.0],
            intensity: [0.5, 0.5, 4.0],
        },
    ];
    let [positions, normals, albedo, _] =
        FLOAT_QUERIES.map(|(_, query, per_texel)| floats(&rt, query, per_texel));
    let direct = engine_direct(&positions, &normals, &albedo, &lights);
    let client = lightfarm_client::direct_from_point_lights(
        &bundle.layout,
        &Occluders::from_layout(&bundle.layout),
        &lights,
    );
    assert_eq!(direct, client.radiance.as_flattened());
    assert!(direct.iter().any(|&v| v > 0.0), "some texels are lit");
    assert!(direct.contains(&0.0), "some face away");
    // Applied through C, the two give the same indirect light.
    let mut from_engine = vec![f32::NAN; direct.len()];
    let mut from_client = vec![f32::NAN; direct.len()];
    let rt_apply = |d: &[f32], out: &mut [f32]| {
        // SAFETY: live runtime; the slices are live for the call.
        unsafe { lf_runtime_apply(rt.0, 0, d.as_ptr(), d.len(), out.as_mut_ptr(), out.len()) }
    };
    assert_eq!(rt_apply(&direct, &mut from_engine), OK);
    assert_eq!(
        rt_apply(client.radiance.as_flattened(), &mut from_client),
        OK
    );
    assert_eq!(from_engine, from_client);
    assert!(from_engine.iter().all(|v| v.is_finite() && *v > 0.0));
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
