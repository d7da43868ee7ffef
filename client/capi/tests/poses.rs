//! `lf_runtime_set_poses` called as C calls it, on a hand-built room of two floor texels with a
//! dynamic object (a square lid) in the bundle: placed over one texel it shadows that texel's
//! direct light wholly and leaves the other's bit for bit, through every direct-light entry
//! point; the room holding it is no longer reported in sight; removing it restores the level's
//! light exactly; and every refused pose names itself and leaves the previous poses in force.

use std::ffi::c_char;
use std::ptr::{null, null_mut};

use lightfarm::*;
use lightfarm_proto::bundle::{DynamicShape, FaceLink, Room, Rooms, SurfacePlace};
use lightfarm_proto::testing::two_texel_bundle;

mod common;

use common::{last_error, Rt, OK};

const LIGHT: LfPointLight = LfPointLight {
    position: [0.25, 0.9, 0.25],
    intensity: [2.0, 1.0, 0.5],
};

/// A closed 1 m room whose floor holds two 0.5 m texels (`testing::two_texel_bundle`), with the
/// rooms section (so a light's reach is walked) and a dynamic object "lid": a 0.2 m square,
/// level, in its own frame.
fn room_bundle() -> Vec<u8> {
    let mut bundle = two_texel_bundle();
    bundle.rooms = Some(Rooms {
        rooms: vec![Room {
            min: [0.0; 3],
            max: [1.0; 3],
            faces: [FaceLink::Closed; 6],
        }],
        surfaces: vec![SurfacePlace::Face { room: 0, face: 2 }],
    });
    let h = 0.1;
    bundle.dynamic_shapes = vec![DynamicShape {
        object: "lid".into(),
        albedo: [0.5; 3],
        triangles: vec![
            [[-h, 0.0, -h], [h, 0.0, -h], [h, 0.0, h]],
            [[-h, 0.0, -h], [h, 0.0, h], [-h, 0.0, h]],
        ],
    }];
    bundle.encode()
}

fn load() -> Rt {
    let bytes = room_bundle();
    // SAFETY: `bytes.len()` readable bytes.
    let rt = unsafe { lf_runtime_new(bytes.as_ptr(), bytes.len()) };
    assert!(!rt.is_null());
    Rt(rt)
}

/// The lid over texel 0, 0.5 m above the floor (its shadow from the light covers every sample
/// of texel 0 and none of texel 1).
fn over_texel_0(id: *const c_char) -> LfPose {
    LfPose {
        id,
        translation: [0.25, 0.5, 0.25],
        rotation: [0.0, 0.0, 0.0, 1.0],
    }
}

/// Direct light through the three entry points: every texel, the light's own reach, and the
/// spans of that reach; with the reach's spans.
fn direct_three_ways(rt: &Rt) -> ([f32; 6], [f32; 6], [f32; 6], Vec<LfTexelSpan>) {
    let (mut all, mut reach, mut spans_out) = ([0.0f32; 6], [0.0f32; 6], [0.0f32; 6]);
    let mut spans = [LfTexelSpan::default(); 4];
    let mut count = 0usize;
    // SAFETY: live runtime; every buffer is live for its call with the length passed.
    unsafe {
        assert_eq!(
            lf_runtime_direct_from_point_lights(rt.0, &LIGHT, 1, all.as_mut_ptr(), 6),
            OK
        );
        assert_eq!(
            lf_runtime_light_direct(
                rt.0,
                &LIGHT,
                spans.as_mut_ptr(),
                spans.len(),
                &mut count,
                reach.as_mut_ptr(),
                6
            ),
            OK
        );
        assert_eq!(
            lf_runtime_direct_in_spans(
                rt.0,
                &LIGHT,
                1,
                spans.as_ptr(),
                count,
                spans_out.as_mut_ptr(),
                6
            ),
            OK
        );
    }
    (all, reach, spans_out, spans[..count].to_vec())
}

#[test]
fn a_posed_object_shadows_direct_light_until_it_is_removed() {
    let rt = load();
    let (level, reach, spans_out, spans) = direct_three_ways(&rt);
    assert!(level.iter().all(|&x| x > 0.0), "{level:?}");
    assert_eq!(reach, level);
    assert_eq!(spans_out, level);
    // The light's own room holds nothing but walls: its floor is in sight.
    assert_eq!(spans.len(), 1);
    assert_eq!(spans[0].in_sight, 1);

    let id = c"lid";
    let pose = over_texel_0(id.as_ptr());
    // SAFETY: live runtime, one readable pose with a live id.
    assert_eq!(unsafe { lf_runtime_set_poses(rt.0, &pose, 1) }, OK);
    let (all, reach, spans_out, spans) = direct_three_ways(&rt);
    assert_eq!(
        &all[..3],
        &[0.0; 3],
        "texel 0 lies wholly in the lid's shadow"
    );
    assert_eq!(
        &all[3..],
        &level[3..],
        "texel 1 keeps its light bit for bit"
    );
    assert_eq!(reach, all);
    assert_eq!(spans_out, all);
    assert_eq!(spans[0].in_sight, 0, "the room holds the lid now");

    // Refused poses leave the lid where it is.
    let nowhere = c"blue_cube";
    let bad_utf8 = [0xffu8, 0];
    let cases: [(LfPose, &str); 4] = [
        (
            over_texel_0(nowhere.as_ptr()),
            "poses[0]: \"blue_cube\" is no dynamic object of this bundle (it has \"lid\")",
        ),
        (over_texel_0(null()), "poses[0]: id is NULL"),
        (
            over_texel_0(bad_utf8.as_ptr().cast()),
            "poses[0]: id is not UTF-8",
        ),
        (
            LfPose {
                translation: [f32::NAN, 0.0, 0.0],
                ..over_texel_0(id.as_ptr())
            },
            "poses[0]: \"lid\": translation or rotation is not finite",
        ),
    ];
    for (pose, message) in cases {
        // SAFETY: live runtime, one readable pose whose id is NULL or a live string.
        let status = unsafe { lf_runtime_set_poses(rt.0, &pose, 1) };
        assert_eq!(status, LfStatus::InvalidPose as i32, "{message}");
        assert!(last_error().contains(message), "{}", last_error());
        assert_eq!(direct_three_ways(&rt).0, all);
    }
    // SAFETY: NULL arguments are refused before any read.
    unsafe {
        assert_eq!(
            lf_runtime_set_poses(null_mut(), &pose, 1),
            LfStatus::NullPointer as i32
        );
        assert_eq!(
            lf_runtime_set_poses(rt.0, null(), 1),
            LfStatus::NullPointer as i32
        );
    }
    assert!(last_error().contains("poses is NULL"), "{}", last_error());

    // No pose: the level's light again, exactly, and the room in sight.
    // SAFETY: live runtime; NULL with a zero count is an empty list.
    assert_eq!(unsafe { lf_runtime_set_poses(rt.0, null(), 0) }, OK);
    let (again, _, _, spans) = direct_three_ways(&rt);
    assert_eq!(again, level);
    assert_eq!(spans[0].in_sight, 1);
}

#[test]
fn a_rotated_pose_moves_the_shadow_with_the_object() {
    let rt = load();
    let id = c"lid";
    // The lid stood on its edge (90° about x) casts almost no shadow straight down; laid flat
    // again by the same rotation's inverse it does.
    let s = std::f32::consts::FRAC_1_SQRT_2;
    let standing = LfPose {
        rotation: [s, 0.0, 0.0, s],
        ..over_texel_0(id.as_ptr())
    };
    // SAFETY: live runtime, one readable pose with a live id.
    assert_eq!(unsafe { lf_runtime_set_poses(rt.0, &standing, 1) }, OK);
    let (edge_on, ..) = direct_three_ways(&rt);
    let flat = LfPose {
        rotation: [0.0, 0.0, 0.0, 2.0],
        ..over_texel_0(id.as_ptr())
    };
    // SAFETY: as above.
    assert_eq!(unsafe { lf_runtime_set_poses(rt.0, &flat, 1) }, OK);
    let (lying, ..) = direct_three_ways(&rt);
    assert!(edge_on[0] > 0.0 && lying[0] == 0.0, "{edge_on:?} {lying:?}");
}
