//! The posed objects' own light called as C calls it, on `testing::ball_bundle` (a probe volume
//! and a DNRT grid for `ball`): `lf_runtime_object_light` writes the client's
//! `ObjectLight` light on its spans, bit for bit, at one bounce and with all bounces, and
//! nothing elsewhere; `lf_runtime_bounce_object_light` adds the client's bounces of it; and
//! every refused call (field not filled, too few spans, no grid for a placed object, no probe
//! volume) names its cause and writes nothing.

use std::ffi::CString;
use std::ptr::{null, null_mut};

use lightfarm::*;
use lightfarm_client::{
    Bounces, DirectLight, IndirectLight, Light, Method, ObjectLight, Occluders, ProbeField, Runtime,
};
use lightfarm_proto::lights::LightKind;
use lightfarm_proto::testing::{ball_bundle, Lcg};

mod common;

use common::{last_error, Rt, OK};

const LAMP: LfPointLight = LfPointLight {
    position: [3.0, 0.0, 3.0],
    intensity: [10.0, 8.0, 6.0],
};

fn lamp() -> Light {
    Light {
        kind: LightKind::Point,
        position: LAMP.position.map(f64::from),
        intensity: LAMP.intensity.map(f64::from),
    }
}

/// `lf_runtime_object_light` into a buffer of `fill` values: (status, spans, light).
fn object_light(
    rt: &Rt,
    n: usize,
    capacity: usize,
    fill: f32,
) -> (i32, Vec<LfTexelSpan>, Vec<f32>) {
    let mut spans = vec![LfTexelSpan::default(); capacity];
    let mut count = usize::MAX;
    let mut out = vec![fill; 3 * n];
    let lights = [LAMP];
    // SAFETY: buffers of the lengths passed.
    let status = unsafe {
        lf_runtime_object_light(
            rt.0,
            lights.as_ptr(),
            1,
            spans.as_mut_ptr(),
            capacity,
            &mut count,
            out.as_mut_ptr(),
            out.len(),
        )
    };
    spans.truncate(count.min(capacity));
    (status, spans, out)
}

fn set_bounces(rt: &Rt, mode: LfBounces) {
    // SAFETY: live runtime.
    assert_eq!(
        unsafe { lf_runtime_set_bounces(rt.0, mode as i32, 0.0) },
        OK
    );
}

/// Fills the C runtime's probe field and the client's from the same light.
fn fill_field(rt: &Rt, client: &mut Runtime, light: &[f32]) -> ProbeField {
    // SAFETY: `light.len()` readable floats.
    let status = unsafe { lf_runtime_apply_probes(rt.0, light.as_ptr(), light.len()) };
    assert_eq!(status, OK, "{}", last_error());
    let direct = DirectLight {
        radiance: light.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
    };
    let mut field = ProbeField::default();
    client.apply_probes(&direct, &mut field).unwrap();
    field
}

#[test]
fn the_objects_light_through_the_c_abi_is_the_clients() {
    let bundle = ball_bundle();
    let rt = Rt::from_bytes(&bundle.encode());
    let mut client = Runtime::new(bundle.clone());
    let n = client.n_texels();
    let level = Occluders::from_layout(&bundle.layout);
    let id = CString::new("ball").unwrap();
    let mut rng = Lcg(5);
    let light: Vec<f32> = (0..3 * n).map(|_| rng.range(0.0, 2.0)).collect();

    // Before the field is filled: refused, nothing written.
    rt.place(&id, [3.0, 0.0, 0.8]);
    let (status, _, out) = object_light(&rt, n, 16, 7.0);
    assert_eq!(status, LfStatus::BadLength as i32);
    assert!(
        last_error().contains("lf_runtime_apply_probes fills it"),
        "{}",
        last_error()
    );
    assert!(out.iter().all(|&v| v == 7.0));

    let field = fill_field(&rt, &mut client, &light);
    let mut objects = ObjectLight::new(&bundle).unwrap();
    for (mode, bounced) in [(LfBounces::One, false), (LfBounces::Converged, true)] {
        set_bounces(&rt, mode);
        for at in [[3.0, 0.0, 0.8], [9.5, 0.3, 1.1]] {
            let pose = rt.place(&id, at);
            let (status, spans, out) = object_light(&rt, n, 16, 7.0);
            assert_eq!(status, OK, "{}", last_error());
            let poses = [pose];
            objects
                .update(&bundle, &field, bounced, &level, &[lamp()], &poses)
                .unwrap();
            let want: Vec<_> = (objects.spans().iter())
                .map(|r| LfTexelSpan {
                    start: r.start as u32,
                    end: r.end as u32,
                    in_sight: 0,
                })
                .collect();
            assert_eq!(spans, want);
            assert!(!spans.is_empty());
            for t in 0..n {
                let inside = objects.spans().iter().any(|r| r.contains(&t));
                let got = [out[3 * t], out[3 * t + 1], out[3 * t + 2]];
                let expected = if inside {
                    objects.light().radiance[t]
                } else {
                    [7.0; 3]
                };
                assert_eq!(got, expected, "texel {t} at {at:?}, {mode:?}");
            }
        }
    }

    // Too few spans: the number needed, nothing written.
    let (status, spans, out) = object_light(&rt, n, 0, 7.0);
    assert_eq!(status, LfStatus::BadLength as i32);
    assert!(
        last_error().contains("out_spans holds 0 but"),
        "{}",
        last_error()
    );
    assert!(spans.is_empty() && out.iter().all(|&v| v == 7.0));

    // Its bounces: the client's, added where they were written (all bounces).
    let mut indirect = IndirectLight {
        radiance: (0..n).map(|t| [0.1 * t as f32, 0.2, 0.3]).collect(),
    };
    let mut c_indirect: Vec<f32> = indirect.radiance.iter().flatten().copied().collect();
    // SAFETY: `c_indirect.len()` readable and writable floats.
    let status = unsafe {
        lf_runtime_bounce_object_light(
            rt.0,
            LfMethod::Mrt as i32,
            c_indirect.as_mut_ptr(),
            c_indirect.len(),
        )
    };
    assert_eq!(status, OK, "{}", last_error());
    let before = indirect.clone();
    objects
        .bounce(&mut client, Method::Mrt, Bounces::default(), &mut indirect)
        .unwrap()
        .unwrap();
    let want: Vec<f32> = indirect.radiance.iter().flatten().copied().collect();
    assert_eq!(c_indirect, want);
    assert_ne!(indirect, before);

    // No object placed: no span, nothing written.
    // SAFETY: no pose to read.
    assert_eq!(unsafe { lf_runtime_set_poses(rt.0, null(), 0) }, OK);
    let (status, spans, out) = object_light(&rt, n, 16, 7.0);
    assert_eq!(status, OK, "{}", last_error());
    assert!(spans.is_empty() && out.iter().all(|&v| v == 7.0));
}

#[test]
fn a_placed_object_needs_its_grid_and_the_probe_volume() {
    let id = CString::new("ball").unwrap();
    // The shape but no grid.
    let mut no_grid = ball_bundle();
    no_grid.dnrt = None;
    let rt = Rt::from_bytes(&no_grid.encode());
    let n = no_grid.layout.n_texels();
    let light = vec![0.5f32; 3 * n];
    // SAFETY: `light.len()` readable floats.
    assert_eq!(
        unsafe { lf_runtime_apply_probes(rt.0, light.as_ptr(), light.len()) },
        OK
    );
    rt.place(&id, [3.0, 0.0, 0.8]);
    let (status, _, out) = object_light(&rt, n, 16, 7.0);
    assert_eq!(status, LfStatus::MissingOperator as i32);
    assert_eq!(
        last_error(),
        "lf_runtime_object_light: pose \"ball\": the bundle has no DNRT grid for it"
    );
    assert!(out.iter().all(|&v| v == 7.0));

    // The shape and its grid but no probe volume.
    let mut no_volume = ball_bundle();
    no_volume.probes = None;
    let rt = Rt::from_bytes(&no_volume.encode());
    rt.place(&id, [3.0, 0.0, 0.8]);
    let (status, _, _) = object_light(&rt, no_volume.layout.n_texels(), 16, 7.0);
    assert_eq!(status, LfStatus::MissingOperator as i32);
    assert_eq!(
        last_error(),
        "lf_runtime_object_light: this bundle has no probe volume"
    );

    // NULL pointers are named.
    // SAFETY: NULL runtime.
    let status = unsafe { lf_runtime_bounce_object_light(null_mut(), 0, null_mut(), 0) };
    assert_eq!(status, LfStatus::NullPointer as i32);
    assert_eq!(last_error(), "lf_runtime_bounce_object_light: rt is NULL");
}
