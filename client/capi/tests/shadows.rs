//! The change of direct light as a placed object moves, called as C calls it, on
//! `testing::ball_bundle` (a dynamic object `ball` over a row of texels): each
//! `lf_runtime_shadow_change` hands over the client's `ShadowChange` between the poses of the
//! last change handed over and the runtime's poses, bit for bit, on its spans only; a call with
//! too few spans writes nothing and the next call hands that change over; other lights start
//! again from the last poses handed over.

use std::ffi::CString;
use std::ptr::null_mut;

use lightfarm::*;
use lightfarm_client::{Light, Occluders, ShadowChange};
use lightfarm_proto::lights::LightKind;
use lightfarm_proto::testing::ball_bundle;

mod common;

use common::{last_error, Rt, OK};

fn client_light(l: &LfPointLight) -> Light {
    Light {
        kind: LightKind::Point,
        position: l.position.map(f64::from),
        intensity: l.intensity.map(f64::from),
    }
}

/// `lf_runtime_shadow_change` into a buffer of `fill` values: (status, span count, spans,
/// change).
fn shadow_change(
    rt: &Rt,
    lights: &[LfPointLight],
    n: usize,
    capacity: usize,
) -> (i32, usize, Vec<LfTexelSpan>, Vec<f32>) {
    let mut spans = vec![LfTexelSpan::default(); capacity];
    let mut count = usize::MAX;
    let mut out = vec![7.0f32; 3 * n];
    // SAFETY: buffers of the lengths passed.
    let status = unsafe {
        lf_runtime_shadow_change(
            rt.0,
            lights.as_ptr(),
            lights.len(),
            spans.as_mut_ptr(),
            capacity,
            &mut count,
            out.as_mut_ptr(),
            out.len(),
        )
    };
    spans.truncate(count.min(capacity));
    (status, count, spans, out)
}

/// The C call's spans and values are `want`'s, and every other texel kept its value.
fn same_as(got: &(i32, usize, Vec<LfTexelSpan>, Vec<f32>), want: &ShadowChange, what: &str) {
    let (status, _, spans, out) = got;
    assert_eq!(*status, OK, "{what}: {}", last_error());
    let expected: Vec<LfTexelSpan> = (want.spans().iter())
        .map(|r| LfTexelSpan {
            start: r.start as u32,
            end: r.end as u32,
            in_sight: 0,
        })
        .collect();
    assert_eq!(*spans, expected, "{what}");
    for (t, rgb) in out.chunks_exact(3).enumerate() {
        let inside = want.spans().iter().any(|r| r.contains(&t));
        let value = if inside {
            want.change().radiance[t]
        } else {
            [7.0; 3]
        };
        assert_eq!(rgb, value, "{what}: texel {t}");
    }
}

#[test]
fn the_change_of_a_moving_objects_shadow_through_the_c_abi_is_the_clients() {
    let bundle = ball_bundle();
    let n = bundle.layout.n_texels();
    let level = Occluders::from_layout(&bundle.layout);
    let rt = Rt::from_bytes(&bundle.encode());
    let id = CString::new("ball").unwrap();
    let lamp = LfPointLight {
        position: [6.0, 0.5, 3.0],
        intensity: [20.0, 16.0, 12.0],
    };
    let lamps = [client_light(&lamp)];

    // The first call: from the poses before the last lf_runtime_set_poses (none at load).
    let at_a = vec![rt.place(&id, [5.5, 0.5, 1.2])];
    let mut client = ShadowChange::new(&bundle, &level, &lamps, 4, &[]);
    client.update(&bundle, &level, &at_a).unwrap();
    let got = shadow_change(&rt, &[lamp], n, 16);
    assert!(!got.2.is_empty(), "the ball shadows some texels");
    same_as(&got, &client, "placed");

    // Moved: the change from there.
    let at_b = vec![rt.place(&id, [6.5, 0.4, 1.3])];
    client.update(&bundle, &level, &at_b).unwrap();
    same_as(&shadow_change(&rt, &[lamp], n, 16), &client, "moved");

    // Too few spans: the number needed and nothing written; the next call hands the change
    // over (the object moved on in between: that move comes with the call after).
    let at_c = vec![rt.place(&id, [4.5, 0.5, 1.1])];
    client.update(&bundle, &level, &at_c).unwrap();
    let (status, count, spans, out) = shadow_change(&rt, &[lamp], n, 0);
    assert_eq!(status, LfStatus::BadLength as i32);
    assert_eq!(count, client.spans().len());
    assert!(
        last_error().contains("out_spans holds 0 but"),
        "{}",
        last_error()
    );
    assert!(spans.is_empty() && out.iter().all(|&v| v == 7.0));
    let at_d = vec![rt.place(&id, [3.5, 0.5, 1.1])];
    same_as(&shadow_change(&rt, &[lamp], n, 16), &client, "handed over");
    client.update(&bundle, &level, &at_d).unwrap();
    same_as(&shadow_change(&rt, &[lamp], n, 16), &client, "after it");

    // Other lights: from the last poses handed over, for those lights.
    let other = LfPointLight {
        position: [4.0, 0.5, 2.5],
        intensity: [5.0; 3],
    };
    let at_e = vec![rt.place(&id, [4.0, 0.5, 1.0])];
    let mut again = ShadowChange::new(&bundle, &level, &[client_light(&other)], 4, &at_d);
    again.update(&bundle, &level, &at_e).unwrap();
    same_as(&shadow_change(&rt, &[other], n, 16), &again, "other lights");

    // Nothing moved: no span. NULL pointers are named.
    let (status, _, spans, out) = shadow_change(&rt, &[other], n, 16);
    assert_eq!(status, OK);
    assert!(spans.is_empty() && out.iter().all(|&v| v == 7.0));
    // SAFETY: a NULL count is refused before anything is read.
    let status = unsafe {
        lf_runtime_shadow_change(rt.0, &other, 1, null_mut(), 0, null_mut(), null_mut(), 0)
    };
    assert_eq!(status, LfStatus::NullPointer as i32);
    assert_eq!(last_error(), "lf_runtime_shadow_change: out_count is NULL");
}
