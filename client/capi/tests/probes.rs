//! The probe volume called as C calls it, on `testing::probe_bundle` (two blocks, a clutter
//! object and seven probes): `lf_runtime_apply_probes` gives the field the client runtime gives,
//! bit for bit, `lf_runtime_apply_probes_delta_in_spans` moves it to the new light's within
//! float rounding reading the spans only, `lf_runtime_probe_irradiance` is the client's
//! `irradiance_at` of that field; and every refused call (no volume, wrong lengths, a span
//! outside the layout, a field not filled yet) names its cause and leaves the field as it was.

use std::ptr::null;

use lightfarm::*;
use lightfarm_client::{irradiance_at, DirectLight, ProbeField, Runtime};
use lightfarm_proto::testing::{drt_bundle, probe_bundle, Lcg};

mod common;

use common::{last_error, Rt, OK};

fn light(rng: &mut Lcg, n: usize) -> Vec<f32> {
    (0..3 * n).map(|_| rng.range(0.0, 2.0)).collect()
}

fn field_of(rt: &Rt) -> Vec<f32> {
    // SAFETY: live runtime.
    let n = unsafe { lf_runtime_probe_count(rt.0) } * LF_PROBE_FLOATS;
    let mut out = vec![f32::NAN; n];
    // SAFETY: `n` writable floats.
    let status = unsafe { lf_runtime_probe_field(rt.0, out.as_mut_ptr(), n) };
    assert_eq!(status, OK, "{}", last_error());
    out
}

#[test]
fn probes_through_the_c_abi_are_the_runtimes() {
    let mut rng = Lcg(41);
    let bundle = probe_bundle(&mut rng, true);
    let bytes = bundle.encode();
    let rt = Rt::from_bytes(&bytes);
    let mut client = Runtime::new(lightfarm_proto::bundle::Bundle::decode(&bytes).unwrap());
    let n = client.n_texels();
    // SAFETY: live runtime.
    assert_eq!(unsafe { lf_runtime_probe_count(rt.0) }, 7);

    // Before any field: reading it or adding a change is refused.
    let mut out = vec![0.0f32; 7 * LF_PROBE_FLOATS];
    // SAFETY: `out.len()` writable floats.
    let status = unsafe { lf_runtime_probe_field(rt.0, out.as_mut_ptr(), out.len()) };
    assert_eq!(status, LfStatus::BadLength as i32);
    assert!(last_error().contains("lf_runtime_apply_probes fills it"));
    let (zeros, all) = (
        vec![0.0f32; 3 * n],
        [LfTexelSpan {
            start: 0,
            end: n as u32,
            in_sight: 0,
        }],
    );
    // SAFETY: readable for their lengths.
    let status = unsafe {
        lf_runtime_apply_probes_delta_in_spans(rt.0, zeros.as_ptr(), zeros.len(), all.as_ptr(), 1)
    };
    assert_eq!(status, LfStatus::BadLength as i32);
    assert_eq!(
        last_error(),
        "lf_runtime_apply_probes_delta_in_spans: the probe field (lf_runtime_apply_probes fills \
         it) holds 0 but 7 are needed"
    );

    let old = light(&mut rng, n);
    // SAFETY: `old.len()` readable floats.
    let status = unsafe { lf_runtime_apply_probes(rt.0, old.as_ptr(), old.len()) };
    assert_eq!(status, OK, "{}", last_error());
    let as_light = |v: &[f32]| DirectLight {
        radiance: v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
    };
    let mut want = ProbeField::default();
    client.apply_probes(&as_light(&old), &mut want).unwrap();
    assert_eq!(
        field_of(&rt),
        want.as_slice(),
        "the same bits as the runtime's"
    );

    let before = field_of(&rt);
    // A change on texels 2..9, garbage elsewhere (not read).
    let spans = [LfTexelSpan {
        start: 2,
        end: 9,
        in_sight: 0,
    }];
    let mut change = vec![1e30f32; 3 * n];
    let mut new = old.clone();
    for t in 2..9 {
        for c in 0..3 {
            let d = rng.range(-0.5, 0.5);
            change[3 * t + c] = d;
            new[3 * t + c] += d;
        }
    }
    // SAFETY: readable for their lengths.
    let status = unsafe {
        lf_runtime_apply_probes_delta_in_spans(
            rt.0,
            change.as_ptr(),
            change.len(),
            spans.as_ptr(),
            spans.len(),
        )
    };
    assert_eq!(status, OK, "{}", last_error());
    client.apply_probes(&as_light(&new), &mut want).unwrap();
    let got = field_of(&rt);
    let scale = want.as_slice().iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(scale > 0.1);
    for (g, w) in got.iter().zip(want.as_slice()) {
        assert!(
            (g - w).abs() <= 1e-5 * scale,
            "{g} by the change, {w} of the new light"
        );
    }
    assert_ne!(got, before, "the change moved the field");

    // Irradiance at a point: the client's lookup of the same field.
    let (p, nrm) = ([0.5f32, 0.75, -0.75], [0.0f32, 1.0, 0.0]);
    let mut e = [f32::NAN; 3];
    // SAFETY: 3 floats each.
    let status =
        unsafe { lf_runtime_probe_irradiance(rt.0, p.as_ptr(), nrm.as_ptr(), e.as_mut_ptr()) };
    assert_eq!(status, OK, "{}", last_error());
    let mut field = ProbeField::default();
    client.apply_probes(&as_light(&new), &mut field).unwrap();
    let volume = client.probe_volume().unwrap();
    let direct = irradiance_at(volume, &field, p, nrm);
    for c in 0..3 {
        assert!(
            (e[c] - direct[c]).abs() <= 1e-4 * (1.0 + direct[c].abs()),
            "{e:?} {direct:?}"
        );
    }
    assert!(e.iter().any(|&v| v > 0.0));

    // Refused calls name their cause and leave the field as it was.
    let kept = field_of(&rt);
    let outside = [LfTexelSpan {
        start: 5,
        end: n as u32 + 1,
        in_sight: 0,
    }];
    // SAFETY: readable for their lengths.
    let status = unsafe {
        lf_runtime_apply_probes_delta_in_spans(
            rt.0,
            change.as_ptr(),
            change.len(),
            outside.as_ptr(),
            1,
        )
    };
    assert_eq!(status, LfStatus::BadIndex as i32);
    assert!(last_error().contains("spans[0]"));
    // SAFETY: one float fewer than the layout needs.
    let status = unsafe { lf_runtime_apply_probes(rt.0, old.as_ptr(), old.len() - 1) };
    assert_eq!(status, LfStatus::BadLength as i32);
    assert!(last_error().contains("leaving_rgb"));
    let mut short = vec![0.0f32; 7 * LF_PROBE_FLOATS - 1];
    // SAFETY: `short.len()` writable floats.
    let status = unsafe { lf_runtime_probe_field(rt.0, short.as_mut_ptr(), short.len()) };
    assert_eq!(status, LfStatus::BadLength as i32);
    // SAFETY: NULL normal.
    let status = unsafe { lf_runtime_probe_irradiance(rt.0, p.as_ptr(), null(), e.as_mut_ptr()) };
    assert_eq!(status, LfStatus::NullPointer as i32);
    assert!(last_error().contains("normal"));
    assert_eq!(field_of(&rt), kept);
}

#[test]
fn a_bundle_without_probes_says_so() {
    let mut rng = Lcg(42);
    let bytes = drt_bundle(&mut rng, true, true, false).encode();
    let rt = Rt::from_bytes(&bytes);
    // SAFETY: live runtime.
    let n = unsafe { lf_runtime_texel_count(rt.0) };
    // SAFETY: live runtime.
    assert_eq!(unsafe { lf_runtime_probe_count(rt.0) }, 0);
    let leaving = vec![1.0f32; 3 * n];
    // SAFETY: `leaving.len()` readable floats.
    let status = unsafe { lf_runtime_apply_probes(rt.0, leaving.as_ptr(), leaving.len()) };
    assert_eq!(status, LfStatus::MissingOperator as i32);
    assert!(last_error().contains("no probe volume"), "{}", last_error());
    let mut e = [0.0f32; 3];
    // SAFETY: 3 floats each.
    let status = unsafe {
        lf_runtime_probe_irradiance(
            rt.0,
            [0.0f32; 3].as_ptr(),
            [0.0f32, 1.0, 0.0].as_ptr(),
            e.as_mut_ptr(),
        )
    };
    assert_eq!(status, LfStatus::MissingOperator as i32);
    // SAFETY: NULL runtime.
    assert_eq!(unsafe { lf_runtime_probe_count(null()) }, 0);
}
