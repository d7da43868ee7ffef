//! Numerical stability, inputs: albedo 0 and 0.99, rank-deficient lighting priors (one prior
//! light, every prior light at one point, coincident lamps, a tolerance that keeps rank 1), and
//! inputs that cannot be baked, refused with an error naming the object and field, never a
//! panic. Bounds: `// measured m; bound b` as measured at the time of writing
//! (texels_per_face 6, 256 rays; reference 2048 rays).

mod stability_common;

use lightfarm_proto::scene::{Scene, Transport};
use lightfarm_tests::apply;
use stability_common::*;

const T: u32 = 6;
const RAYS: u32 = 256;
const REF_RAYS: u32 = 2048;

/// Two rooms through an opening, a crate in the first; `albedo` for the walls, `crate_albedo`
/// for the crate, `extra` appended to the scene object.
fn rooms(albedo: f64, floor: f64, crate_albedo: f64, extra: &str) -> String {
    format!(
        r#"{{ "format": "lightfarm.scene/1", "name": "rooms",
             "blocks": [
               {{ "id": "room", "min": [0,0,0], "max": [4,3,4], "open": ["+x"], "albedo": [{albedo},{albedo},{albedo}],
                  "face_albedo": {{ "-y": [{floor},{floor},{floor}] }} }},
               {{ "id": "annex", "min": [4,0,0], "max": [7,3,4], "open": ["-x"], "albedo": [{albedo},{albedo},{albedo}] }} ],
             "clutter": [ {{ "id": "crate", "box": {{ "min": [1.5,0,1.5], "max": [2.5,1.2,2.5] }},
                            "albedo": [{crate_albedo},{crate_albedo},{crate_albedo}] }} ]
             {extra} }}"#
    )
}

fn lamp() -> lightfarm_proto::lights::LightSet {
    one_light([0.8, 2.4, 1.0], 6.0)
}

/// Albedo 0 everywhere: no direct radiance leaves a surface and the indirect light is exactly
/// zero, through both transports, DRT and the reference.
#[test]
fn albedo_zero_everywhere_is_exactly_dark() {
    let scene = scene(&rooms(0.0, 0.0, 0.0, ""), T, RAYS);
    let dir = no_meshes();
    let lights = lamp();
    let reference = reference(&scene, &dir, &lights, 256);
    for transport in [Transport::Lightfield, Transport::Traced] {
        let (_, ours) = bake_and_apply_deterministically(
            &format!("albedo 0, {transport:?}"),
            &scene,
            &dir,
            transport,
            &lights,
        );
        for r in [&ours, &reference] {
            assert!(r
                .texels
                .iter()
                .all(|t| t.direct == [0.0; 3] && t.indirect == [0.0; 3]));
        }
    }
}

/// Albedo 0.99 on every wall and the crate (one bounce reflects nearly all it receives; the flux
/// bound is tight), and a black floor and crate under white walls.
#[test]
fn albedo_zero_point_nine_nine_and_black_next_to_white() {
    let dir = no_meshes();
    let lights = lamp();
    // (label, walls, floor, crate, bound)
    for (label, walls, floor, crate_albedo, bound) in [
        // Flux: ours 0.991, the reference 1.004 of the one-bounce maximum.
        // measured 0.0570 (Lightfield) / 0.0539 (Traced); bound 0.09
        ("albedo 0.99", 0.99, 0.99, 0.99, 0.09),
        // measured 0.0732 / 0.0681; bound 0.11
        ("black floor and crate, walls 0.99", 0.99, 0.0, 0.0, 0.11),
    ] {
        let scene = scene(&rooms(walls, floor, crate_albedo, ""), T, RAYS);
        let reference = reference(&scene, &dir, &lights, REF_RAYS);
        for transport in [Transport::Lightfield, Transport::Traced] {
            let m = check_case(
                &format!("{label}, {transport:?}"),
                &scene,
                &dir,
                transport,
                &lights,
                &reference,
                bound,
            );
            // Black surfaces reflect nothing.
            for t in &m.result.texels {
                if t.albedo == [0.0; 3] {
                    assert_eq!(t.indirect, [0.0; 3], "{label}: black {} lit", t.surface);
                }
            }
        }
    }
}

/// Rank-deficient priors: one prior light per block (inside a closed block; in the slab beyond
/// the opening of an open one, so none inside), every prior light at one point (a light region
/// a nanometre wide), and a tolerance of 0.9 (rank 1).
#[test]
fn rank_deficient_priors() {
    let dir = no_meshes();
    let lights = lamp();
    let one_point = r#", "light_regions": [ { "min": [0.8, 2.4, 1.0], "max": [0.800000001, 2.400000001, 1.000000001] } ]"#;
    let closed = r#"{ "format": "lightfarm.scene/1", "name": "closed",
        "blocks": [ { "id": "box", "min": [0,0,0], "max": [4,3,4], "albedo": [0.7,0.7,0.7] } ] }"#;
    // A prior of rank ~1 per face cannot represent a lamp away from its one light position:
    // the error is large by design, and the light it cannot represent is lost, never gained
    // (flux 0.36–0.49 of the reference's 0.98–1.01). What is checked is that it stays finite,
    // deterministic and energy-bounded, and does not get worse.
    // (label, scene, prior lights, tolerance, bound)
    let cases = [
        // measured 0.6796; bound 0.8
        (
            "one prior light, closed box",
            closed.to_string(),
            1,
            1e-3,
            0.8,
        ),
        // With openings half the prior lights go beyond them: with one, none is inside.
        // measured 0.6100; bound 0.75
        (
            "one prior light, open blocks",
            rooms(0.7, 0.7, 0.5, ""),
            1,
            1e-3,
            0.75,
        ),
        // The lamp is at the point: the prior spans it.
        // measured 0.0588; bound 0.09
        (
            "prior lights at one point",
            rooms(0.7, 0.7, 0.5, one_point),
            64,
            1e-3,
            0.09,
        ),
        // measured 0.7107; bound 0.85
        ("tolerance 0.9", rooms(0.7, 0.7, 0.5, ""), 768, 0.9, 0.85),
    ];
    for (label, json, prior_lights, tolerance, bound) in cases {
        let mut scene = scene(&json, T, RAYS);
        scene.settings.prior_lights = prior_lights;
        scene.settings.tolerance = tolerance;
        let reference = reference(&scene, &dir, &lights, REF_RAYS);
        check_case(
            label,
            &scene,
            &dir,
            Transport::Lightfield,
            &lights,
            &reference,
            bound,
        );
    }
}

/// Two lamps at one position give what one lamp of twice the intensity gives.
#[test]
fn coincident_lamps() {
    let dir = no_meshes();
    let scene = scene(&rooms(0.7, 0.7, 0.5, ""), T, RAYS);
    let twin = lights(
        r#"{ "lights": [ { "kind": "point", "position": [0.8, 2.4, 1.0], "intensity": [3, 3, 3] },
                         { "kind": "point", "position": [0.8, 2.4, 1.0], "intensity": [3, 3, 3] } ] }"#,
    );
    let reference = reference(&scene, &dir, &twin, REF_RAYS);
    // measured 0.0604; bound 0.09
    let m = check_case(
        "coincident lamps",
        &scene,
        &dir,
        Transport::Lightfield,
        &twin,
        &reference,
        0.09,
    );
    let single = apply(&m.bundle, &lamp(), lightfarm_client::Method::Drt);
    let d = distance(&m.result, &single);
    eprintln!("two coincident lamps vs one of twice the intensity: {d:.2e}");
    // measured 0 (bit-identical); bound 1e-6
    assert!(d <= 1e-6, "{d}");
}

const VALID: &str = r#"{ "format": "lightfarm.scene/1", "name": "ok",
    "blocks": [ { "id": "a", "min": [0,0,0], "max": [4,3,4], "open": ["+x"], "albedo": [0.7,0.7,0.7] },
                { "id": "b", "min": [4,0,0], "max": [7,3,4], "open": ["-x"], "albedo": [0.7,0.7,0.7] } ],
    "clutter": [ { "id": "c", "box": { "min": [1,0,1], "max": [2,1,2] }, "albedo": [0.5,0.5,0.5] } ] }"#;

/// `VALID` with `from` replaced by `to` (once; the replacement must apply).
fn edit(from: &str, to: &str) -> String {
    assert_eq!(VALID.matches(from).count(), 1, "{from}");
    VALID.replacen(from, to, 1)
}

/// Scenes that cannot be baked are refused by validation with a message naming the object and
/// the field, never a panic.
#[test]
fn unbakeable_scenes_are_refused_with_the_object_and_field_named() {
    Scene::from_json(VALID).unwrap();
    let a_min = r#""id": "a", "min": [0,0,0], "max": [4,3,4]"#;
    let c_box = r#""box": { "min": [1,0,1], "max": [2,1,2] }"#;
    let cases: Vec<(String, Vec<&str>)> = vec![
        // A zero-extent block (a wall with no room behind it).
        (
            edit(a_min, r#""id": "a", "min": [0,0,0], "max": [4,0,4]"#),
            vec!["block \"a\"", "max.y (0) <= min.y (0)"],
        ),
        (
            edit(a_min, r#""id": "a", "min": [0,0,0], "max": [-4,3,4]"#),
            vec!["block \"a\"", "max.x (-4) <= min.x (0)"],
        ),
        // A coordinate beyond f64 (JSON has no NaN).
        (
            edit(a_min, r#""id": "a", "min": [0,0,0], "max": [4,3,1e999]"#),
            vec!["scene JSON"],
        ),
        (
            edit(
                r#""id": "a", "min": [0,0,0], "max": [4,3,4], "open": ["+x"], "albedo": [0.7,0.7,0.7]"#,
                r#""id": "a", "min": [0,0,0], "max": [4,3,4], "open": ["+x"], "albedo": [1.0,0.7,0.7]"#,
            ),
            vec!["block \"a\"", "albedo[0] (1) is outside [0, 1)"],
        ),
        (
            edit(r#""albedo": [0.5,0.5,0.5]"#, r#""albedo": [0.5,-0.1,0.5]"#),
            vec!["clutter \"c\"", "albedo[1] (-0.1) is outside [0, 1)"],
        ),
        (
            edit(
                r#""open": ["-x"], "albedo": [0.7,0.7,0.7]"#,
                r#""open": ["-x"], "albedo": [0.7,0.7,0.7], "face_albedo": { "+y": [0.5, 1.5, 0.5] }"#,
            ),
            vec!["block \"b\"", "face_albedo.+y[1] (1.5) is outside [0, 1)"],
        ),
        // Zero-extent and inverted clutter boxes.
        (
            edit(c_box, r#""box": { "min": [1,0,1], "max": [1,1,2] }"#),
            vec!["clutter \"c\"", "box.max.x (1) <= box.min.x (1)"],
        ),
        (
            edit(c_box, r#""box": { "min": [1,0,1], "max": [2,1,0] }"#),
            vec!["clutter \"c\"", "box.max.z (0) <= box.min.z (1)"],
        ),
        (
            edit(
                c_box,
                r#""box": { "min": [1,0,1], "max": [2,1,2] }, "mesh": "m.obj""#,
            ),
            vec!["clutter \"c\"", "either box or mesh"],
        ),
        (
            edit(c_box, r#""mesh": "../../etc/passwd.obj""#),
            vec![
                "clutter \"c\"",
                "relative path inside the scene's directory",
            ],
        ),
        (
            edit(
                c_box,
                r#""mesh": "m.obj", "transform": { "scale": [1, 0, 1] }"#,
            ),
            vec!["clutter \"c\"", "transform.scale.y is zero"],
        ),
        (
            edit(
                c_box,
                r#""mesh": "m.obj", "transform": { "rotation": [0, 0, 0, 0] }"#,
            ),
            vec![
                "clutter \"c\"",
                "transform.rotation is not a unit quaternion",
            ],
        ),
        // A light region with no volume.
        (
            edit(
                r#""clutter": ["#,
                r#""light_regions": [ { "min": [1,1,1], "max": [1,2,2] } ], "clutter": ["#,
            ),
            vec!["light_regions[0]", "max.x (1) <= min.x (1)"],
        ),
        // Blocks that overlap, openings that do not coincide, open against closed.
        (
            edit(
                r#""id": "b", "min": [4,0,0]"#,
                r#""id": "b", "min": [3,0,0]"#,
            ),
            vec!["block \"a\"", "overlaps block \"b\""],
        ),
        (
            edit(
                r#""id": "b", "min": [4,0,0], "max": [7,3,4]"#,
                r#""id": "b", "min": [4,0,0], "max": [7,3,3]"#,
            ),
            vec!["block \"a\"", "partially overlaps face -x of block \"b\""],
        ),
        (
            edit(r#""open": ["-x"], "albedo""#, r#""open": [], "albedo""#),
            vec![
                "block \"a\"",
                "open face +x lies against closed face -x of block \"b\"",
            ],
        ),
        (
            edit(
                r#""open": ["-x"], "albedo""#,
                r#""open": ["-x", "-x"], "albedo""#,
            ),
            vec!["block \"b\"", "open lists -x twice"],
        ),
        (
            edit(r#""id": "b""#, r#""id": "a""#),
            vec!["block \"a\"", "duplicate id"],
        ),
        // Settings out of range.
        (
            edit(
                r#""name": "ok","#,
                r#""name": "ok", "settings": { "texels_per_face": 0 },"#,
            ),
            vec!["settings", "texels_per_face (0)"],
        ),
        (
            edit(
                r#""name": "ok","#,
                r#""name": "ok", "settings": { "rays_per_texel": 0 },"#,
            ),
            vec!["settings", "rays_per_texel (0)"],
        ),
        (
            edit(
                r#""name": "ok","#,
                r#""name": "ok", "settings": { "prior_lights": 0 },"#,
            ),
            vec!["settings", "prior_lights (0)"],
        ),
        (
            edit(
                r#""name": "ok","#,
                r#""name": "ok", "settings": { "tolerance": 0 },"#,
            ),
            vec!["settings", "tolerance (0)"],
        ),
        (
            edit(
                r#""name": "ok","#,
                r#""name": "ok", "settings": { "tolerance": 1 },"#,
            ),
            vec!["settings", "tolerance (1)"],
        ),
        (
            edit(
                r#""name": "ok","#,
                r#""name": "ok", "settings": { "probe_spacing": 0 },"#,
            ),
            vec!["settings", "probe_spacing (0)"],
        ),
        (
            edit(
                r#""name": "ok","#,
                r#""name": "ok", "settings": { "lightfield_cells": 0 },"#,
            ),
            vec!["settings", "lightfield_cells (0)"],
        ),
        (
            r#"{ "format": "lightfarm.scene/1", "name": "empty", "blocks": [] }"#.to_string(),
            vec!["blocks", "at least one block"],
        ),
        (
            VALID.replace(r#""blocks": [ "#, r#""blocks": [ ], "unused": [ "#),
            vec!["scene JSON", "unknown field `unused`"],
        ),
    ];
    for (json, expected) in &cases {
        let err = assert_refused(json, expected);
        eprintln!("refused: {err}");
    }
}

/// 1 m probe spacing over a 7 km level with clutter is 8·10¹⁰ probe grid points: refused with
/// the setting named (before, the bake tried to allocate them and aborted the process).
#[test]
fn a_probe_grid_too_large_to_allocate_is_refused() {
    let json = VALID
        .replace("[4,3,4]", "[4000,3000,4000]")
        .replace("[4,0,0]", "[4000,0,0]")
        .replace("[7,3,4]", "[7000,3000,4000]");
    let err = assert_refused(
        &json,
        &["settings", "probe_spacing (1)", "raise probe_spacing"],
    );
    eprintln!("refused: {err}");
    // The same level without clutter bakes no probe volume and is accepted; so is the level
    // with a coarser grid.
    let mut scene: serde_json::Value = serde_json::from_str(&json).unwrap();
    scene["clutter"] = serde_json::json!([]);
    Scene::from_json(&scene.to_string()).unwrap();
    Scene::from_json(&json.replace(
        r#""name": "ok","#,
        r#""name": "ok", "settings": { "probe_spacing": 100 },"#,
    ))
    .unwrap();
}

/// Scenes built in code (not parsed) are validated by the bake itself: non-finite coordinates,
/// zero extents, albedo 1, zero texels, a NaN light region are refused, never a panic.
#[test]
fn scenes_built_in_code_are_refused_by_the_bake() {
    let dir = no_meshes();
    let valid = Scene::from_json(VALID).unwrap();
    type Edit = fn(&mut Scene);
    let cases: [(Edit, &[&str]); 7] = [
        (
            |s| s.blocks[0].min[1] = f64::NAN,
            &["block \"a\"", "min.y is not finite"],
        ),
        (
            |s| s.blocks[1].max[2] = f64::INFINITY,
            &["block \"b\"", "max.z is not finite"],
        ),
        (
            |s| s.blocks[0].max[1] = 0.0,
            &["block \"a\"", "max.y (0) <= min.y (0)"],
        ),
        (
            |s| s.clutter[0].albedo = [1.0; 3],
            &["clutter \"c\"", "albedo[0] (1)"],
        ),
        (
            |s| s.settings.texels_per_face = 0,
            &["settings", "texels_per_face (0)"],
        ),
        (
            |s| s.settings.probe_spacing = f64::NAN,
            &["settings", "probe_spacing (NaN)"],
        ),
        (
            |s| {
                s.light_regions = vec![lightfarm_proto::scene::Aabb {
                    min: [0.0; 3],
                    max: [1.0, f64::NAN, 1.0],
                }]
            },
            &["light_regions[0]", "max.y is not finite"],
        ),
    ];
    for (edit, expected) in cases {
        let mut scene = valid.clone();
        edit(&mut scene);
        let err = assert_bake_refused(&scene, &dir, expected);
        eprintln!("refused: {err}");
    }
}

/// Lamps the light-set parser refuses (negative intensity), and lamps built in code with a NaN
/// position or exactly at a texel centre: the client skips what has no direction and stays
/// finite.
#[test]
fn lamps_without_a_direction_are_skipped_not_propagated() {
    use lightfarm_proto::lights::{Light, LightKind, LightSet};
    let err = LightSet::from_json(
        r#"{ "lights": [ { "kind": "point", "position": [1, 1, 1], "intensity": [1, -1, 1] } ] }"#,
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("lights[0]") && err.contains("intensity"),
        "{err}"
    );
    let dir = no_meshes();
    let scene = scene(&rooms(0.7, 0.7, 0.5, ""), T, RAYS);
    let (bundle, _) = bake_and_apply_deterministically(
        "bundle for odd lamps",
        &scene,
        &dir,
        Transport::Lightfield,
        &lamp(),
    );
    let lamp_at = |position: [f64; 3]| LightSet {
        lights: vec![Light {
            kind: LightKind::Point,
            position,
            intensity: [5.0; 3],
        }],
        poses: vec![],
    };
    // Floor texel (1, 1) of a 6×6 floor over 4 m: its centre is (1, 0, 1).
    for (label, lights) in [
        ("NaN position", lamp_at([f64::NAN, 1.0, 1.0])),
        ("at a texel centre", lamp_at([1.0, 0.0, 1.0])),
    ] {
        let r = std::panic::catch_unwind(|| apply(&bundle, &lights, lightfarm_client::Method::Drt))
            .unwrap_or_else(|_| panic!("{label}: apply panicked"));
        assert_finite(label, &r);
    }
}
