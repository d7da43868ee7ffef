//! Validation of `lightfarm.scene/1`: one case per error `Scene::from_json` reports (with the
//! exact text the CLI and the HTTP API show), the connectivity graph of valid scenes, and
//! property tests that parsing never panics and that valid boxes always validate.

#![allow(clippy::approx_constant)] // JSON fixtures spell out unit quaternions

use std::fmt::Display;

use lightfarm_proto::scene::{
    Aabb, Block, Connection, Opening, Scene, SceneError, Settings, SCENE_FORMAT,
};
use lightfarm_proto::Face;
use proptest::prelude::*;
use proptest::test_runner::Config as ProptestConfig;
use serde_json::{json, Value};

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

/// A valid one-block scene: block "a" is [0,0,0]-[4,3,4], all faces closed.
fn base() -> Value {
    json!({
        "format": SCENE_FORMAT,
        "name": "test",
        "blocks": [
            { "id": "a", "min": [0, 0, 0], "max": [4, 3, 4], "albedo": [0.5, 0.5, 0.5] }
        ]
    })
}

/// A valid scene exercising every section: two connected blocks, a box and a mesh prop, a
/// dynamic object, a light region and explicit settings.
fn rich() -> Value {
    json!({
        "format": SCENE_FORMAT,
        "name": "rich",
        "settings": {
            "texels_per_face": 8,
            "rays_per_texel": 64,
            "tolerance": 0.01,
            "transport": "traced",
            "lightfield_cells": 2,
            "lightfield_directions": 3,
            "prior_lights": 16,
            "seed": 7
        },
        "blocks": [
            { "id": "a", "min": [0, 0, 0], "max": [4, 3, 4], "open": ["+x", "+y"],
              "albedo": [0.5, 0.5, 0.5], "face_albedo": { "-z": [0.1, 0.2, 0.3] } },
            { "id": "b", "min": [4, 0, 0], "max": [8, 3, 4], "open": ["-x"],
              "albedo": [0.7, 0.6, 0.5] }
        ],
        "clutter": [
            { "id": "crate", "box": { "min": [1, 0, 1], "max": [2, 1, 2] }, "albedo": [0.4, 0.3, 0.2] },
            { "id": "chair", "mesh": "chair.glb",
              "transform": { "translation": [5, 0, 2], "rotation": [0, 0.7071067811865476, 0, 0.7071067811865476], "scale": [1, 1, 1] },
              "albedo": [0.3, 0.3, 0.3] }
        ],
        "dynamic": [
            { "id": "robot", "mesh": "robot.gltf", "albedo": [0.2, 0.2, 0.2] }
        ],
        "light_regions": [
            { "min": [0, 0, 0], "max": [8, 3, 4] }
        ]
    })
}

/// Returns `v` with the node at JSON pointer `pointer` set to `value`; the last segment may
/// name a new object key or the index one past the end of an array (an append).
fn with(mut v: Value, pointer: &str, value: Value) -> Value {
    let (parent, key) = pointer.rsplit_once('/').expect("pointer starts with '/'");
    let parent = v
        .pointer_mut(parent)
        .unwrap_or_else(|| panic!("no parent at {pointer}"));
    match parent {
        Value::Object(map) => {
            map.insert(key.to_string(), value);
        }
        Value::Array(items) => {
            let k: usize = key.parse().expect("array index");
            if k == items.len() {
                items.push(value);
            } else {
                items[k] = value;
            }
        }
        other => panic!("cannot set {pointer} inside {other}"),
    }
    v
}

/// Returns `v` without the object key at `pointer`.
fn without(mut v: Value, pointer: &str) -> Value {
    let (parent, key) = pointer.rsplit_once('/').expect("pointer starts with '/'");
    v.pointer_mut(parent)
        .and_then(Value::as_object_mut)
        .and_then(|m| m.remove(key))
        .unwrap_or_else(|| panic!("nothing at {pointer}"));
    v
}

/// A block with the given id, extent and open faces.
fn block(id: &str, min: [f64; 3], max: [f64; 3], open: &[&str]) -> Value {
    json!({ "id": id, "min": min, "max": max, "open": open, "albedo": [0.5, 0.5, 0.5] })
}

/// `base()` with its blocks replaced.
fn blocks(list: Vec<Value>) -> Value {
    with(base(), "/blocks", Value::Array(list))
}

/// `base()` with one clutter object.
fn clutter(c: Value) -> Value {
    with(base(), "/clutter", json!([c]))
}

/// `base()` with one settings field set.
fn setting(field: &str, value: Value) -> Value {
    with(base(), "/settings", json!({ field: value }))
}

/// Parses `json` (a `&str`, `String` or `serde_json::Value`) and asserts that it is refused
/// with a message containing `expected`. Returns the error for further checks.
fn check(json: impl Display, expected: &str) -> SceneError {
    let text = json.to_string();
    match Scene::from_json(&text) {
        Ok(_) => {
            panic!("expected an error containing {expected:?}, but the scene was accepted:\n{text}")
        }
        Err(err) => {
            let msg = err.to_string();
            assert!(
                msg.contains(expected),
                "error message {msg:?} does not contain {expected:?}\nscene: {text}"
            );
            err
        }
    }
}

/// Like [`check`], but the whole message must be exactly `expected`.
fn check_exact(json: impl Display, expected: &str) -> SceneError {
    let err = check(json, expected);
    assert_eq!(err.to_string(), expected);
    err
}

/// Parses `json` and asserts it is accepted.
fn ok(json: impl Display) -> Scene {
    let text = json.to_string();
    Scene::from_json(&text).unwrap_or_else(|e| panic!("expected Ok, got {e}\nscene: {text}"))
}

/// Asserts the connectivity graph is symmetric: every `Neighbour` points back, and
/// `connections()` lists each such pair exactly once.
fn assert_graph_consistent(scene: &Scene) {
    let openings = scene.openings().expect("validated scene has openings");
    assert_eq!(openings.len(), scene.blocks.len());
    let mut pairs = 0;
    for (i, faces) in openings.iter().enumerate() {
        for face in Face::ALL {
            let slot = faces[face.index()];
            assert_eq!(
                slot.is_some(),
                scene.blocks[i].is_open(face),
                "block {i} face {face}: opening present iff the face is open"
            );
            if let Some(Opening::Neighbour { block, face: back }) = slot {
                assert_ne!(block, i);
                assert_eq!(back, face.opposite());
                assert_eq!(
                    openings[block][back.index()],
                    Some(Opening::Neighbour { block: i, face }),
                    "block {i} face {face} leads to block {block} face {back}, which does not lead back"
                );
                if i < block {
                    pairs += 1;
                }
            }
        }
    }
    let connections = scene
        .connections()
        .expect("validated scene has connections");
    assert_eq!(connections.len(), pairs);
    for c in &connections {
        assert!(c.block_a < c.block_b);
    }
}

// ---------------------------------------------------------------------------------------------
// The fixtures themselves are valid
// ---------------------------------------------------------------------------------------------

#[test]
fn base_and_rich_fixtures_are_valid() {
    let scene = ok(base());
    assert_eq!(scene.settings, Settings::default());
    assert!(scene.connections().unwrap().is_empty());
    let rich = ok(rich());
    assert_graph_consistent(&rich);
    // The validated scene survives a serialise/parse round trip.
    let again = ok(serde_json::to_string(&rich).unwrap());
    assert_eq!(again, rich);
}

// ---------------------------------------------------------------------------------------------
// Format and JSON structure
// ---------------------------------------------------------------------------------------------

#[test]
fn wrong_format_string() {
    check_exact(
        with(base(), "/format", json!("lightfarm.scene/2")),
        r#"format: expected "lightfarm.scene/1", got "lightfarm.scene/2""#,
    );
}

#[test]
fn format_that_is_not_a_string() {
    check_exact(
        with(base(), "/format", json!(1)),
        r#"format: expected "lightfarm.scene/1", got "1""#,
    );
}

#[test]
fn missing_format() {
    let err = check_exact(
        without(base(), "/format"),
        "scene JSON: missing field `format`",
    );
    assert!(matches!(err, SceneError::Json(_)));
}

#[test]
fn missing_name() {
    check_exact(without(base(), "/name"), "scene JSON: missing field `name`");
}

#[test]
fn not_json_at_all() {
    let err = check("{\"format\": ", "scene JSON: EOF while parsing");
    assert!(matches!(err, SceneError::Json(_)));
    check(
        "1",
        "scene JSON: invalid type: integer `1`, expected struct Scene",
    );
    // serde also reads structs from JSON arrays (field order); an empty one is too short.
    check("[]", "scene JSON: invalid length 0, expected struct Scene");
    check("", "scene JSON: EOF while parsing a value");
}

#[test]
fn unknown_top_level_field() {
    check(
        with(base(), "/colour", json!("red")),
        "scene JSON: unknown field `colour`, expected one of `format`, `name`, `settings`, `blocks`",
    );
}

#[test]
fn unknown_block_field() {
    check(
        with(base(), "/blocks/0/colour", json!([1, 0, 0])),
        "scene JSON: unknown field `colour`, expected one of `id`, `min`, `max`, `open`, `albedo`, `face_albedo`",
    );
}

#[test]
fn unknown_settings_field() {
    check(
        setting("texels", json!(8)),
        "scene JSON: unknown field `texels`, expected one of `texels_per_face`",
    );
}

#[test]
fn unknown_face_name() {
    check(
        with(base(), "/blocks/0/open", json!(["+w"])),
        "unknown variant `+w`",
    );
}

#[test]
fn unknown_transport() {
    check(
        setting("transport", json!("magic")),
        "unknown variant `magic`, expected `lightfield` or `traced`",
    );
}

// ---------------------------------------------------------------------------------------------
// Blocks
// ---------------------------------------------------------------------------------------------

#[test]
fn block_max_not_above_min() {
    let v = with(base(), "/blocks/0/min", json!([0, 3, 0]));
    let v = with(v, "/blocks/0/max", json!([4, 0, 4]));
    check_exact(v, r#"block "a": max.y (0) <= min.y (3)"#);
}

#[test]
fn block_with_zero_extent() {
    check_exact(
        with(base(), "/blocks/0/max", json!([4, 3, 0])),
        r#"block "a": max.z (0) <= min.z (0)"#,
    );
}

#[test]
fn block_with_fractional_coordinates_reports_them_exactly() {
    check_exact(
        with(base(), "/blocks/0/max", json!([-0.25, 3, 4])),
        r#"block "a": max.x (-0.25) <= min.x (0)"#,
    );
}

#[test]
fn non_finite_coordinate_is_rejected_by_the_json_parser() {
    // JSON has no NaN/Infinity literal; a number that overflows f64 is refused by serde_json
    // ("number out of range") before validation sees it.
    let text = base()
        .to_string()
        .replace("\"max\":[4,3,4]", "\"max\":[1e400,3,4]");
    assert!(text.contains("1e400"));
    let err = check(&text, "scene JSON: number out of range");
    assert!(matches!(err, SceneError::Json(_)));

    let text = base()
        .to_string()
        .replace("\"min\":[0,0,0]", "\"min\":[0,-1e400,0]");
    assert!(text.contains("-1e400"));
    check(&text, "scene JSON: number out of range");

    // The literals themselves are not JSON.
    let text = base()
        .to_string()
        .replace("\"max\":[4,3,4]", "\"max\":[NaN,3,4]");
    check(&text, "scene JSON: expected value");
    let text = base()
        .to_string()
        .replace("\"max\":[4,3,4]", "\"max\":[Infinity,3,4]");
    check(&text, "scene JSON: expected value");
}

#[test]
fn non_finite_coordinate_is_rejected_by_validate() {
    // Scenes built in code (not parsed) go through the same checks.
    let mut scene = ok(base());
    scene.blocks[0].max[0] = f64::INFINITY;
    assert_eq!(
        scene.validate().unwrap_err().to_string(),
        r#"block "a": max.x is not finite (inf)"#
    );
    scene.blocks[0].max[0] = 4.0;
    scene.blocks[0].min[2] = f64::NAN;
    assert_eq!(
        scene.validate().unwrap_err().to_string(),
        r#"block "a": min.z is not finite (NaN)"#
    );
    scene.blocks[0].min[2] = 0.0;
    scene.blocks[0].albedo[1] = f64::NAN;
    assert_eq!(
        scene.validate().unwrap_err().to_string(),
        r#"block "a": albedo.y is not finite (NaN)"#
    );
}

#[test]
fn albedo_one_is_rejected() {
    check_exact(
        with(base(), "/blocks/0/albedo", json!([1.0, 0.5, 0.5])),
        r#"block "a": albedo[0] (1) is outside [0, 1)"#,
    );
}

#[test]
fn negative_albedo_is_rejected() {
    check_exact(
        with(base(), "/blocks/0/albedo", json!([0.5, -0.1, 0.5])),
        r#"block "a": albedo[1] (-0.1) is outside [0, 1)"#,
    );
}

#[test]
fn albedo_bounds_are_half_open() {
    ok(with(base(), "/blocks/0/albedo", json!([0.0, 0.0, 0.0])));
    ok(with(
        base(),
        "/blocks/0/albedo",
        json!([0.999999, 0.5, 0.5]),
    ));
}

#[test]
fn face_albedo_out_of_range() {
    check_exact(
        with(
            base(),
            "/blocks/0/face_albedo",
            json!({ "+y": [0.5, 1.5, 0.5] }),
        ),
        r#"block "a": face_albedo.+y[1] (1.5) is outside [0, 1)"#,
    );
    check_exact(
        with(
            base(),
            "/blocks/0/face_albedo",
            json!({ "-x": [0.5, 0.5, -0.5] }),
        ),
        r#"block "a": face_albedo.-x[2] (-0.5) is outside [0, 1)"#,
    );
}

#[test]
fn duplicate_block_id() {
    check_exact(
        blocks(vec![
            block("a", [0.0; 3], [4.0, 3.0, 4.0], &[]),
            block("a", [10.0, 0.0, 0.0], [14.0, 3.0, 4.0], &[]),
        ]),
        r#"block "a": duplicate id"#,
    );
}

#[test]
fn duplicate_clutter_id() {
    let v = with(
        base(),
        "/clutter",
        json!([
            { "id": "c", "box": { "min": [1, 0, 1], "max": [2, 1, 2] }, "albedo": [0.5, 0.5, 0.5] },
            { "id": "c", "mesh": "c.obj", "albedo": [0.5, 0.5, 0.5] }
        ]),
    );
    check_exact(v, r#"clutter "c": duplicate id"#);
}

#[test]
fn duplicate_dynamic_id() {
    let v = with(
        base(),
        "/dynamic",
        json!([
            { "id": "d", "mesh": "d.obj", "albedo": [0.5, 0.5, 0.5] },
            { "id": "d", "mesh": "d.glb", "albedo": [0.5, 0.5, 0.5] }
        ]),
    );
    check_exact(v, r#"dynamic "d": duplicate id"#);
}

const ID_RULE: &str = r#"id must be 1-128 characters without '/', '"', '\' or control characters"#;

#[test]
fn empty_id() {
    check_exact(
        with(base(), "/blocks/0/id", json!("")),
        &format!(r#"block "": {ID_RULE}"#),
    );
}

#[test]
fn id_with_forbidden_characters_or_too_long() {
    check_exact(
        with(base(), "/blocks/0/id", json!("a/b")),
        &format!(r#"block "a/b": {ID_RULE}"#),
    );
    check(with(base(), "/blocks/0/id", json!("a\"b")), ID_RULE);
    check(with(base(), "/blocks/0/id", json!("a\\b")), ID_RULE);
    check(with(base(), "/blocks/0/id", json!("a\nb")), ID_RULE);
    let long = "x".repeat(129);
    check_exact(
        with(base(), "/blocks/0/id", json!(long)),
        &format!(r#"block "{long}": {ID_RULE}"#),
    );
    ok(with(base(), "/blocks/0/id", json!("x".repeat(128))));
}

#[test]
fn open_face_listed_twice() {
    check_exact(
        with(base(), "/blocks/0/open", json!(["+x", "-y", "+x"])),
        r#"block "a": open lists +x twice"#,
    );
}

#[test]
fn empty_blocks_list() {
    check_exact(
        with(base(), "/blocks", json!([])),
        "blocks: a scene needs at least one block",
    );
}

#[test]
fn missing_blocks() {
    check_exact(
        without(base(), "/blocks"),
        "scene JSON: missing field `blocks`",
    );
}

// ---------------------------------------------------------------------------------------------
// Connectivity between blocks
// ---------------------------------------------------------------------------------------------

#[test]
fn blocks_overlapping_in_volume() {
    check_exact(
        blocks(vec![
            block("a", [0.0; 3], [4.0, 3.0, 4.0], &[]),
            block("b", [2.0, 1.0, 1.0], [6.0, 4.0, 5.0], &[]),
        ]),
        r#"block "a": overlaps block "b""#,
    );
}

#[test]
fn block_inside_another() {
    check_exact(
        blocks(vec![
            block("outer", [0.0; 3], [10.0; 3], &[]),
            block("inner", [1.0; 3], [2.0; 3], &[]),
        ]),
        r#"block "outer": overlaps block "inner""#,
    );
}

#[test]
fn touching_closed_blocks_are_fine() {
    // Back-to-back walls, and blocks sharing only an edge.
    let scene = ok(blocks(vec![
        block("a", [0.0; 3], [4.0, 3.0, 4.0], &[]),
        block("b", [4.0, 0.0, 0.0], [8.0, 3.0, 4.0], &[]),
        block("c", [4.0, 3.0, 0.0], [8.0, 6.0, 4.0], &[]),
    ]));
    assert!(scene.connections().unwrap().is_empty());
}

#[test]
fn open_face_against_closed_face() {
    check_exact(
        blocks(vec![
            block("a", [0.0; 3], [4.0, 3.0, 4.0], &["+x"]),
            block("b", [4.0, 0.0, 0.0], [8.0, 3.0, 4.0], &[]),
        ]),
        r#"block "a": open face +x lies against closed face -x of block "b""#,
    );
}

#[test]
fn closed_face_against_open_face_names_the_open_block_first() {
    check_exact(
        blocks(vec![
            block("a", [0.0; 3], [4.0, 3.0, 4.0], &[]),
            block("b", [4.0, 0.0, 0.0], [8.0, 3.0, 4.0], &["-x"]),
        ]),
        r#"block "b": open face -x lies against closed face +x of block "a""#,
    );
}

#[test]
fn open_face_partially_overlapping_open_face() {
    check_exact(
        blocks(vec![
            block("a", [0.0; 3], [4.0, 3.0, 4.0], &["+x"]),
            block("b", [4.0, 0.0, 2.0], [8.0, 3.0, 6.0], &["-x"]),
        ]),
        r#"block "a": face +x partially overlaps face -x of block "b"; openings must coincide exactly"#,
    );
}

#[test]
fn open_face_covered_by_two_neighbours() {
    check(
        blocks(vec![
            block("a", [0.0; 3], [4.0, 3.0, 4.0], &["+x"]),
            block("b", [4.0, 0.0, 0.0], [8.0, 3.0, 2.0], &["-x"]),
            block("c", [4.0, 0.0, 2.0], [8.0, 3.0, 4.0], &["-x"]),
        ]),
        r#"block "a": face +x partially overlaps face -x of block "b""#,
    );
}

#[test]
fn open_face_inside_a_larger_closed_wall() {
    // a's whole +x face lies against part of b's closed -x wall: refused.
    check(
        blocks(vec![
            block("a", [0.0; 3], [4.0, 3.0, 4.0], &["+x"]),
            block("b", [4.0, -1.0, -1.0], [8.0, 5.0, 6.0], &[]),
        ]),
        r#"block "a": face +x partially overlaps face -x of block "b""#,
    );
}

#[test]
fn valid_connection() {
    let scene = ok(blocks(vec![
        block("a", [0.0; 3], [4.0, 3.0, 4.0], &["+x"]),
        block("b", [4.0, 0.0, 0.0], [8.0, 3.0, 4.0], &["-x"]),
    ]));
    assert_eq!(
        scene.connections().unwrap(),
        vec![Connection {
            block_a: 0,
            face_a: Face::PosX,
            block_b: 1,
            face_b: Face::NegX
        }]
    );
    let openings = scene.openings().unwrap();
    assert_eq!(
        openings[0][Face::PosX.index()],
        Some(Opening::Neighbour {
            block: 1,
            face: Face::NegX
        })
    );
    assert_eq!(
        openings[1][Face::NegX.index()],
        Some(Opening::Neighbour {
            block: 0,
            face: Face::PosX
        })
    );
    assert_graph_consistent(&scene);
}

#[test]
fn valid_connection_listed_in_reverse_order() {
    let scene = ok(blocks(vec![
        block("b", [4.0, 0.0, 0.0], [8.0, 3.0, 4.0], &["-x"]),
        block("a", [0.0; 3], [4.0, 3.0, 4.0], &["+x"]),
    ]));
    assert_eq!(
        scene.connections().unwrap(),
        vec![Connection {
            block_a: 0,
            face_a: Face::NegX,
            block_b: 1,
            face_b: Face::PosX
        }]
    );
}

#[test]
fn same_pair_with_neighbour_face_closed() {
    check_exact(
        blocks(vec![
            block("a", [0.0; 3], [4.0, 3.0, 4.0], &["+x"]),
            block("b", [4.0, 0.0, 0.0], [8.0, 3.0, 4.0], &["+x"]),
        ]),
        r#"block "a": open face +x lies against closed face -x of block "b""#,
    );
}

#[test]
fn open_face_without_neighbour_opens_onto_the_void() {
    let scene = ok(with(base(), "/blocks/0/open", json!(["+y"])));
    let openings = scene.openings().unwrap();
    for face in Face::ALL {
        let expected = (face == Face::PosY).then_some(Opening::Void);
        assert_eq!(openings[0][face.index()], expected, "face {face}");
    }
    assert!(scene.connections().unwrap().is_empty());
}

#[test]
fn connection_between_blocks_far_from_the_origin() {
    // Coordinates whose tolerance (relative to the block's scale) differs between the blocks.
    let scene = ok(blocks(vec![
        block("a", [1e6, 0.0, 0.0], [1e6 + 4.0, 3.0, 4.0], &["+x"]),
        block("b", [1e6 + 4.0, 0.0, 0.0], [1e6 + 8.0, 3.0, 4.0], &["-x"]),
    ]));
    assert_eq!(scene.connections().unwrap().len(), 1);
    assert_graph_consistent(&scene);
}

#[test]
fn connectivity_is_symmetric_when_blocks_have_different_scales() {
    // a is small and near the origin, b reaches 1e6; their faces are 1e-6 apart, within the
    // tolerance of the larger block (1e-9 * 1e6). Both sides must see the connection, in either
    // order: a Neighbour on one side and Void on the other would hand the bake engine an
    // inconsistent graph (this used to happen: the tolerance was taken from one block only).
    let a = block("a", [0.0; 3], [4.0, 3.0, 4.0], &["+x"]);
    let b = block("b", [4.0 + 1e-6, 0.0, 0.0], [1e6, 3.0, 4.0], &["-x"]);
    let scene = ok(blocks(vec![a.clone(), b.clone()]));
    assert_graph_consistent(&scene);
    assert_eq!(
        scene.connections().unwrap(),
        vec![Connection {
            block_a: 0,
            face_a: Face::PosX,
            block_b: 1,
            face_b: Face::NegX
        }]
    );
    let scene = ok(blocks(vec![b, a]));
    assert_graph_consistent(&scene);
    assert_eq!(
        scene.connections().unwrap(),
        vec![Connection {
            block_a: 0,
            face_a: Face::NegX,
            block_b: 1,
            face_b: Face::PosX
        }]
    );
}

// ---------------------------------------------------------------------------------------------
// Clutter and dynamic objects
// ---------------------------------------------------------------------------------------------

#[test]
fn clutter_with_box_and_mesh() {
    check_exact(
        clutter(
            json!({ "id": "c", "box": { "min": [1, 0, 1], "max": [2, 1, 2] }, "mesh": "c.obj", "albedo": [0.5, 0.5, 0.5] }),
        ),
        r#"clutter "c": give either box or mesh, not both"#,
    );
}

#[test]
fn clutter_with_neither_box_nor_mesh() {
    check_exact(
        clutter(json!({ "id": "c", "albedo": [0.5, 0.5, 0.5] })),
        r#"clutter "c": needs a box or a mesh"#,
    );
}

#[test]
fn clutter_mesh_with_bad_extension() {
    check_exact(
        clutter(json!({ "id": "c", "mesh": "props/chair.fbx", "albedo": [0.5, 0.5, 0.5] })),
        r#"clutter "c": mesh "props/chair.fbx" is not .obj, .gltf or .glb"#,
    );
    // The extension check is case-insensitive.
    ok(clutter(
        json!({ "id": "c", "mesh": "props/CHAIR.GLTF", "albedo": [0.5, 0.5, 0.5] }),
    ));
}

#[test]
fn clutter_mesh_with_empty_path() {
    check_exact(
        clutter(json!({ "id": "c", "mesh": "", "albedo": [0.5, 0.5, 0.5] })),
        r#"clutter "c": mesh path is empty"#,
    );
}

#[test]
fn clutter_box_max_not_above_min() {
    check_exact(
        clutter(
            json!({ "id": "c", "box": { "min": [1, 0, 1], "max": [0.5, 1, 2] }, "albedo": [0.5, 0.5, 0.5] }),
        ),
        r#"clutter "c": box.max.x (0.5) <= box.min.x (1)"#,
    );
}

#[test]
fn clutter_box_with_transform() {
    check_exact(
        clutter(
            json!({ "id": "c", "box": { "min": [1, 0, 1], "max": [2, 1, 2] },
                        "transform": { "translation": [1, 0, 0] }, "albedo": [0.5, 0.5, 0.5] }),
        ),
        r#"clutter "c": transform applies to meshes only; give the box in world coordinates"#,
    );
}

#[test]
fn clutter_albedo_out_of_range() {
    check_exact(
        clutter(json!({ "id": "c", "mesh": "c.obj", "albedo": [0.5, 0.5, 1.0] })),
        r#"clutter "c": albedo[2] (1) is outside [0, 1)"#,
    );
}

#[test]
fn clutter_transform_with_non_unit_quaternion() {
    check_exact(
        clutter(
            json!({ "id": "c", "mesh": "c.obj", "transform": { "rotation": [0, 0, 0, 2] }, "albedo": [0.5, 0.5, 0.5] }),
        ),
        r#"clutter "c": transform.rotation is not a unit quaternion (norm 2)"#,
    );
    check(
        clutter(
            json!({ "id": "c", "mesh": "c.obj", "transform": { "rotation": [0, 0, 0, 0] }, "albedo": [0.5, 0.5, 0.5] }),
        ),
        r#"clutter "c": transform.rotation is not a unit quaternion (norm 0)"#,
    );
}

#[test]
fn clutter_transform_with_zero_scale() {
    check_exact(
        clutter(
            json!({ "id": "c", "mesh": "c.obj", "transform": { "scale": [1, 0, 1] }, "albedo": [0.5, 0.5, 0.5] }),
        ),
        r#"clutter "c": transform.scale.y is zero"#,
    );
}

#[test]
fn clutter_transform_with_unknown_field() {
    check(
        clutter(
            json!({ "id": "c", "mesh": "c.obj", "transform": { "skew": [1, 0, 1] }, "albedo": [0.5, 0.5, 0.5] }),
        ),
        "unknown field `skew`, expected one of `translation`, `rotation`, `scale`",
    );
}

#[test]
fn dynamic_object_with_bad_mesh_extension() {
    check_exact(
        with(
            base(),
            "/dynamic",
            json!([{ "id": "d", "mesh": "robot.fbx", "albedo": [0.5, 0.5, 0.5] }]),
        ),
        r#"dynamic "d": mesh "robot.fbx" is not .obj, .gltf or .glb"#,
    );
}

#[test]
fn dynamic_object_with_albedo_out_of_range() {
    check_exact(
        with(
            base(),
            "/dynamic",
            json!([{ "id": "d", "mesh": "robot.obj", "albedo": [2, 0.5, 0.5] }]),
        ),
        r#"dynamic "d": albedo[0] (2) is outside [0, 1)"#,
    );
}

// ---------------------------------------------------------------------------------------------
// Light regions
// ---------------------------------------------------------------------------------------------

#[test]
fn light_region_max_not_above_min() {
    check_exact(
        with(
            base(),
            "/light_regions",
            json!([{ "min": [0, 0, 0], "max": [4, 3, 4] }, { "min": [0, 0, 1], "max": [4, 3, 1] }]),
        ),
        "light_regions[1]: max.z (1) <= min.z (1)",
    );
}

// ---------------------------------------------------------------------------------------------
// Settings
// ---------------------------------------------------------------------------------------------

#[test]
fn settings_texels_per_face_zero() {
    check_exact(
        setting("texels_per_face", json!(0)),
        "settings: texels_per_face (0) must be in 1..=128",
    );
    check_exact(
        setting("texels_per_face", json!(129)),
        "settings: texels_per_face (129) must be in 1..=128",
    );
}

#[test]
fn settings_codec_error_outside_zero_one() {
    check_exact(
        setting("codec_error", json!(0.0)),
        "settings: codec_error (0) must be in (0, 1)",
    );
    check_exact(
        setting("codec_error", json!(1.5)),
        "settings: codec_error (1.5) must be in (0, 1)",
    );
    check_exact(
        setting("transport_codec_error", json!(-0.01)),
        "settings: transport_codec_error (-0.01) must be in (0, 1)",
    );
    check_exact(
        setting("transport_codec_error", json!(1.0)),
        "settings: transport_codec_error (1) must be in (0, 1)",
    );
}

#[test]
fn settings_unknown_bundle_codec() {
    let err = Scene::from_json(&setting("bundle_codec", json!("u4")).to_string()).unwrap_err();
    assert!(err.to_string().contains("u4"), "{err}");
}

#[test]
fn settings_rays_per_texel_zero() {
    check_exact(
        setting("rays_per_texel", json!(0)),
        "settings: rays_per_texel (0) must be in 1..=1048576",
    );
}

#[test]
fn settings_tolerance_zero() {
    check_exact(
        setting("tolerance", json!(0)),
        "settings: tolerance (0) must be in (0, 1)",
    );
}

#[test]
fn settings_tolerance_one() {
    check_exact(
        setting("tolerance", json!(1)),
        "settings: tolerance (1) must be in (0, 1)",
    );
}

#[test]
fn settings_lightfield_cells_zero() {
    check_exact(
        setting("lightfield_cells", json!(0)),
        "settings: lightfield_cells (0) must be in 1..=32",
    );
}

#[test]
fn settings_lightfield_directions_and_prior_lights_zero() {
    check_exact(
        setting("lightfield_directions", json!(0)),
        "settings: lightfield_directions (0) must be in 1..=32",
    );
    check_exact(
        setting("prior_lights", json!(0)),
        "settings: prior_lights (0) must be in 1..=65536",
    );
}

#[test]
fn settings_negative_count_is_a_json_error() {
    let err = check(
        setting("texels_per_face", json!(-1)),
        "scene JSON: invalid value: integer `-1`",
    );
    assert!(matches!(err, SceneError::Json(_)));
}

// ---------------------------------------------------------------------------------------------
// Property tests
// ---------------------------------------------------------------------------------------------

fn config() -> ProptestConfig {
    ProptestConfig {
        cases: 256,
        // Keep the source tree clean: no proptest-regressions/ files.
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

/// One textual edit of a JSON document (positions are taken modulo the current length).
#[derive(Clone, Debug)]
enum Edit {
    Delete(prop::sample::Index, usize),
    Insert(prop::sample::Index, String),
    Replace(prop::sample::Index, char),
    Duplicate(prop::sample::Index, usize),
}

fn edit() -> impl Strategy<Value = Edit> {
    let json_char = prop_oneof![
        prop::sample::select(vec![
            '{', '}', '[', ']', ',', ':', '"', '-', '+', '.', 'e', '0', '1', '9', ' ', '\\', 'n'
        ]),
        any::<char>(),
    ];
    prop_oneof![
        (any::<prop::sample::Index>(), 1usize..16).prop_map(|(i, n)| Edit::Delete(i, n)),
        (
            any::<prop::sample::Index>(),
            "[\\[\\]{},:\"0-9eE.+\\-a-z ]{1,8}|.{1,4}"
        )
            .prop_map(|(i, s)| Edit::Insert(i, s)),
        (any::<prop::sample::Index>(), json_char).prop_map(|(i, c)| Edit::Replace(i, c)),
        (any::<prop::sample::Index>(), 1usize..32).prop_map(|(i, n)| Edit::Duplicate(i, n)),
    ]
}

fn apply(text: &str, edits: &[Edit]) -> String {
    let mut chars: Vec<char> = text.chars().collect();
    for e in edits {
        let len = chars.len();
        match e {
            Edit::Delete(i, n) if len > 0 => {
                let at = i.index(len);
                chars.drain(at..(at + n).min(len));
            }
            Edit::Insert(i, s) => {
                let at = i.index(len + 1);
                chars.splice(at..at, s.chars());
            }
            Edit::Replace(i, c) if len > 0 => {
                chars[i.index(len)] = *c;
            }
            Edit::Duplicate(i, n) if len > 0 => {
                let at = i.index(len);
                let piece: Vec<char> = chars[at..(at + n).min(len)].to_vec();
                chars.splice(at..at, piece);
            }
            _ => {}
        }
    }
    chars.into_iter().collect()
}

/// An arbitrary JSON value to put in place of a node of a valid scene.
fn replacement() -> impl Strategy<Value = Value> {
    let number = prop_oneof![
        any::<f64>().prop_filter_map("finite", |x| serde_json::Number::from_f64(x)
            .map(Value::Number)),
        any::<i64>().prop_map(Value::from),
        any::<u64>().prop_map(Value::from),
        prop::sample::select(vec![
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.5,
            0.999_999_999,
            1e-300,
            1e300,
            4.0,
            8.0,
            3.0
        ])
        .prop_map(Value::from),
    ];
    let leaf = prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::Bool),
        number,
        prop::sample::select(vec![
            "-x",
            "+x",
            "-y",
            "+y",
            "-z",
            "+z",
            "",
            "a",
            "b",
            "m.obj",
            "lightfarm.scene/1",
            "traced"
        ])
        .prop_map(Value::from),
        ".{0,8}".prop_map(Value::String),
    ];
    leaf.prop_recursive(2, 12, 4, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..5).prop_map(Value::Array),
            prop::collection::btree_map("[a-z_]{1,6}|box|mesh|min|max|open|id", inner, 0..3)
                .prop_map(|m| Value::Object(m.into_iter().collect())),
        ]
    })
}

/// Every JSON pointer in `v`, the root included.
fn pointers(v: &Value, here: String, out: &mut Vec<String>) {
    match v {
        Value::Object(map) => {
            for (k, child) in map {
                pointers(
                    child,
                    format!("{here}/{}", k.replace('~', "~0").replace('/', "~1")),
                    out,
                );
            }
        }
        Value::Array(items) => {
            for (k, child) in items.iter().enumerate() {
                pointers(child, format!("{here}/{k}"), out);
            }
        }
        _ => {}
    }
    out.push(here);
}

/// Structural mutations of a valid scene: replace or remove nodes.
#[derive(Clone, Debug)]
enum Mutation {
    Replace(prop::sample::Index, Value),
    Remove(prop::sample::Index),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        3 => (any::<prop::sample::Index>(), replacement()).prop_map(|(i, v)| Mutation::Replace(i, v)),
        1 => any::<prop::sample::Index>().prop_map(Mutation::Remove),
    ]
}

fn mutate(mut v: Value, mutations: &[Mutation]) -> Value {
    for m in mutations {
        let mut all = Vec::new();
        pointers(&v, String::new(), &mut all);
        match m {
            Mutation::Replace(i, new) => {
                let p = &all[i.index(all.len())];
                *v.pointer_mut(p).unwrap() = new.clone();
            }
            Mutation::Remove(i) => {
                let p = all[i.index(all.len())].clone();
                if let Some((parent, key)) = p.rsplit_once('/') {
                    match v.pointer_mut(parent) {
                        Some(Value::Object(map)) => {
                            map.remove(&key.replace("~1", "/").replace("~0", "~"));
                        }
                        Some(Value::Array(items)) => {
                            items.remove(key.parse::<usize>().unwrap());
                        }
                        _ => {}
                    }
                }
            }
        }
    }
    v
}

/// Whatever `from_json` returns, it returns (no panic); an accepted scene is fully consistent.
fn parse_without_panic(text: &str) {
    if let Ok(scene) = Scene::from_json(text) {
        scene
            .validate()
            .expect("from_json returned a scene validate() refuses");
        assert_graph_consistent(&scene);
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn arbitrary_strings_never_panic(text in any::<String>()) {
        parse_without_panic(&text);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..256)) {
        parse_without_panic(&String::from_utf8_lossy(&bytes));
    }

    #[test]
    fn textual_mutations_of_a_valid_scene_never_panic(
        use_rich in any::<bool>(),
        edits in prop::collection::vec(edit(), 1..6),
    ) {
        let source = if use_rich { rich() } else { base() };
        let pretty = serde_json::to_string_pretty(&source).unwrap();
        parse_without_panic(&apply(&pretty, &edits));
        parse_without_panic(&apply(&source.to_string(), &edits));
    }

    #[test]
    fn structural_mutations_of_a_valid_scene_never_panic(
        mutations in prop::collection::vec(mutation(), 1..4),
    ) {
        parse_without_panic(&mutate(rich(), &mutations).to_string());
    }

    #[test]
    fn valid_single_boxes_validate(
        min in prop::array::uniform3(-1e6f64..1e6),
        extent in prop::array::uniform3(1e-3f64..1e3),
        albedo in prop::array::uniform3(0.0f64..1.0),
        open in prop::collection::btree_set(prop::sample::select(Face::ALL.to_vec()), 0..=6),
    ) {
        let max = [min[0] + extent[0], min[1] + extent[1], min[2] + extent[2]];
        let scene = Scene {
            format: SCENE_FORMAT.to_string(),
            name: "box".to_string(),
            settings: Settings::default(),
            blocks: vec![Block {
                id: "box".to_string(),
                min,
                max,
                open: open.iter().copied().collect(),
                albedo,
                face_albedo: Default::default(),
                piece: None,
            }],
            clutter: vec![],
            dynamic: vec![],
            light_regions: vec![Aabb { min, max }],
        };
        prop_assert_eq!(scene.validate(), Ok(()));
        let text = serde_json::to_string(&scene).unwrap();
        let parsed = Scene::from_json(&text);
        prop_assert!(parsed.is_ok(), "{:?} for {}", parsed, text);
        let parsed = parsed.unwrap();
        let openings = parsed.openings().unwrap();
        for face in Face::ALL {
            let expected = open.contains(&face).then_some(Opening::Void);
            prop_assert_eq!(openings[0][face.index()], expected);
        }
        prop_assert!(parsed.connections().unwrap().is_empty());
    }

    #[test]
    fn two_adjacent_blocks_agree_on_their_connection(
        // Block a near the origin, block b beyond a's +x face, possibly far away and possibly
        // separated by a tiny gap; both faces open. Accepted scenes must have a symmetric graph.
        a_min in prop::array::uniform3(-10.0f64..10.0),
        a_ext in prop::array::uniform3(0.5f64..10.0),
        b_len in prop::sample::select(vec![1.0, 10.0, 1e3, 1e6, 1e9]),
        gap in prop::sample::select(vec![0.0, 1e-12, 1e-9, 1e-7, 1e-5, 1e-3]),
        b_first in any::<bool>(),
    ) {
        let a_max = [a_min[0] + a_ext[0], a_min[1] + a_ext[1], a_min[2] + a_ext[2]];
        let b_min = [a_max[0] + gap, a_min[1], a_min[2]];
        let b_max = [b_min[0] + b_len, a_max[1], a_max[2]];
        let a = block("a", a_min, a_max, &["+x"]);
        let b = block("b", b_min, b_max, &["-x"]);
        let v = blocks(if b_first { vec![b, a] } else { vec![a, b] });
        if let Ok(scene) = Scene::from_json(&v.to_string()) {
            assert_graph_consistent(&scene);
        }
    }
}

#[test]
fn mesh_paths_may_not_leave_the_scene_directory() {
    for path in ["/etc/x.obj", "../x.obj", "a/../../x.obj", "C:/x.obj"] {
        let json = format!(
            r#"{{ "format": "lightfarm.scene/1", "name": "s", "blocks": [ {{ "id": "a", "min": [0,0,0], "max": [4,3,4], "albedo": [0.5,0.5,0.5] }} ],
                 "clutter": [ {{ "id": "m", "mesh": "{path}", "albedo": [0.5,0.5,0.5] }} ] }}"#
        );
        let err = lightfarm_proto::scene::Scene::from_json(&json)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("must be a relative path inside the scene's directory"),
            "{path}: {err}"
        );
    }
}

#[test]
fn dynamic_regions_are_boxes_and_every_object_must_list_them_to_narrow_the_probes() {
    let robot = |regions: Value| {
        json!([{ "id": "robot", "mesh": "robot.gltf", "albedo": [0.2, 0.2, 0.2],
                 "regions": regions }])
    };
    let v = with(
        rich(),
        "/dynamic",
        robot(json!([{ "min": [1, 0, 1], "max": [1, 2, 3] }])),
    );
    check_exact(
        v,
        r#"dynamic "robot": regions[0].max.x (1) <= regions[0].min.x (1)"#,
    );
    let v = with(
        rich(),
        "/dynamic",
        robot(json!([{ "min": [0, 0, 0], "max": [1, 1, 1] }, { "min": [2, 0, 0] }])),
    );
    assert!(
        Scene::from_json(&v.to_string()).is_err(),
        "a region without max"
    );

    // Every object lists regions: the probes follow them, grown by one probe spacing.
    let v = with(
        rich(),
        "/dynamic",
        robot(json!([{ "min": [1, 0, 1], "max": [2, 1, 3] }])),
    );
    let scene = Scene::from_json(&v.to_string()).unwrap();
    let s = scene.settings.probe_spacing;
    let regions = scene
        .probe_regions()
        .expect("every dynamic object lists regions");
    assert_eq!(regions.len(), 1);
    assert_eq!(regions[0].min, [1.0 - s, -s, 1.0 - s]);
    assert_eq!(regions[0].max, [2.0 + s, 1.0 + s, 3.0 + s]);
    // One object without regions may go anywhere: the whole level.
    let mut two = v.clone();
    two["dynamic"]
        .as_array_mut()
        .unwrap()
        .push(json!({ "id": "cat", "mesh": "cat.glb", "albedo": [0.5, 0.5, 0.5] }));
    assert_eq!(
        Scene::from_json(&two.to_string()).unwrap().probe_regions(),
        None
    );
    assert_eq!(
        Scene::from_json(&rich().to_string())
            .unwrap()
            .probe_regions(),
        None
    );
}

// ---------------------------------------------------------------------------------------------
// Openings: the windowed search against the pairwise loop it replaced
// ---------------------------------------------------------------------------------------------

/// The JSON names of the faces `open` says are open, in `Face::ALL` order.
fn open_names(open: [bool; 6]) -> Vec<&'static str> {
    ["-x", "+x", "-y", "+y", "-z", "+z"]
        .into_iter()
        .zip(open)
        .filter(|(_, o)| *o)
        .map(|(n, _)| n)
        .collect()
}

/// The pairwise loop over every block `Scene::openings` once was (`O(n²)`): its answer, or its
/// first error as text.
fn openings_by_pairs(scene: &Scene) -> Result<Vec<[Option<Opening>; 6]>, String> {
    let scale = |b: &Aabb| {
        b.min
            .iter()
            .chain(b.max.iter())
            .fold(1.0f64, |m, x| m.max(x.abs()))
    };
    let mut out = vec![[None; 6]; scene.blocks.len()];
    for (i, a) in scene.blocks.iter().enumerate() {
        for face in Face::ALL {
            let (amin, amax, ac) = a.aabb().face_rect(face);
            let mut found = None;
            for (j, b) in scene.blocks.iter().enumerate() {
                if i == j {
                    continue;
                }
                let other = face.opposite();
                let (bmin, bmax, bc) = b.aabb().face_rect(other);
                let tol = 1e-9 * scale(&a.aabb()).max(scale(&b.aabb()));
                if (ac - bc).abs() > tol {
                    continue;
                }
                if !(0..2).all(|k| amin[k].max(bmin[k]) < amax[k].min(bmax[k]) - tol) {
                    continue;
                }
                let same = (0..2)
                    .all(|k| (amin[k] - bmin[k]).abs() <= tol && (amax[k] - bmax[k]).abs() <= tol);
                let (a_open, b_open) = (a.is_open(face), b.is_open(other));
                if !a_open && !b_open {
                    continue;
                }
                if !same {
                    return Err(format!(
                        "block \"{}\": face {face} partially overlaps face {other} of block \"{}\"; \
                         openings must coincide exactly",
                        a.id, b.id
                    ));
                }
                if a_open != b_open {
                    let (open, closed, of, cf) = if a_open {
                        (&a.id, &b.id, face, other)
                    } else {
                        (&b.id, &a.id, other, face)
                    };
                    return Err(format!(
                        "block \"{open}\": open face {of} lies against closed face {cf} of \
                         block \"{closed}\""
                    ));
                }
                found = Some(Opening::Neighbour {
                    block: j,
                    face: other,
                });
            }
            if a.is_open(face) {
                out[i][face.index()] = Some(found.unwrap_or(Opening::Void));
            }
        }
    }
    Ok(out)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    /// Grid levels (cells of random widths, some empty, random open faces, some blocks shifted
    /// or stretched off the grid, and stacked storeys): `openings` answers what the pairwise
    /// loop answers, errors included.
    #[test]
    fn openings_equal_the_pairwise_loop(
        cells in proptest::collection::vec(
            (any::<bool>(), 0u8..64, 0u8..8, 0u8..3), 1..40),
        widths in proptest::collection::vec(1u8..6, 8),
        columns in 1usize..7,
        walls in any::<u64>(),
        consistent in any::<bool>(),
    ) {
        let xs: Vec<f64> = std::iter::once(0.0)
            .chain(widths.iter().scan(0.0, |x, w| { *x += *w as f64 * 0.75; Some(*x) }))
            .collect();
        let mut list = Vec::new();
        for (k, &(present, open_bits, nudge, storey)) in cells.iter().enumerate() {
            if !present {
                continue;
            }
            let (cx, cz) = (k % columns, k / columns);
            let (cz, cx) = (cz.min(7), cx.min(7));
            let mut min = [xs[cx], 3.0 * storey as f64, xs[cz]];
            let mut max = [xs[cx + 1], 3.0 * storey as f64 + 3.0, xs[cz + 1]];
            // Now and then a block off the grid: shifted by a fraction, or stretched.
            match nudge {
                1 => { min[0] += 0.25; max[0] += 0.25; }
                2 => max[2] += 0.5,
                _ => {}
            }
            // Consistent: each wall (between two cells, or two storeys) open on both sides or
            // on neither, so that most levels connect without error; else each face at random.
            let wall = |axis: usize, x: usize, z: usize, y: usize| {
                walls >> ((axis * 29 + x * 7 + z * 3 + y * 11) % 64) & 1 == 1
            };
            let st = storey as usize;
            let faces_open = if consistent {
                [
                    wall(0, cx, cz, st),
                    wall(0, cx + 1, cz, st),
                    wall(1, cx, cz, st),
                    wall(1, cx, cz, st + 1),
                    wall(2, cx, cz, st),
                    wall(2, cx, cz + 1, st),
                ]
            } else {
                std::array::from_fn(|f| open_bits & (1 << f) != 0)
            };
            let open = open_names(faces_open);
            list.push(block(&format!("b{k}"), min, max, &open));
        }
        prop_assume!(!list.is_empty());
        // Not validated: overlapping blocks still have openings to compare.
        let scene: Scene = serde_json::from_value(blocks(list)).unwrap();
        let got = scene.openings().map_err(|e| e.to_string());
        prop_assert_eq!(got, openings_by_pairs(&scene));
    }
}

/// A whole two-storey 6 × 6 grid with consistent walls: levels that connect without error, many
/// faces linked, as the windowed search and the pairwise loop both find.
#[test]
fn openings_of_connected_grids_equal_the_pairwise_loop() {
    let mut linked = 0;
    for seed in 0..40u64 {
        let walls = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ (seed << 17);
        let open_of = |axis: usize, x: usize, z: usize, y: usize| {
            walls >> ((axis * 29 + x * 7 + z * 3 + y * 11) % 64) & 1 == 1
        };
        let mut list = Vec::new();
        for (x, z, y) in
            (0..6).flat_map(|x| (0..6).flat_map(move |z| (0..2).map(move |y| (x, z, y))))
        {
            let faces = [
                open_of(0, x, z, y) && x > 0,
                open_of(0, x + 1, z, y) && x < 5,
                open_of(1, x, z, y) && y > 0,
                open_of(1, x, z, y + 1) && y < 1,
                open_of(2, x, z, y) && z > 0,
                open_of(2, x, z + 1, y) && z < 5,
            ];
            let open = open_names(faces);
            let (x0, z0, y0) = (x as f64 * 2.5, z as f64 * 3.0, y as f64 * 3.0);
            list.push(block(
                &format!("c{x}_{z}_{y}"),
                [x0, y0, z0],
                [x0 + 2.5, y0 + 3.0, z0 + 3.0],
                &open,
            ));
        }
        let scene = ok(blocks(list));
        let got = scene.openings().unwrap();
        assert_eq!(Ok(got.clone()), openings_by_pairs(&scene), "seed {seed}");
        linked += got
            .iter()
            .flatten()
            .filter(|f| matches!(f, Some(Opening::Neighbour { .. })))
            .count();
    }
    assert!(linked > 40 * 72 / 4, "{linked} linked faces");
}

/// The first pair of blocks (in block order) whose boxes share a volume, by the loop over every
/// pair (what `Scene::validate` answered before it searched by x), as its error message.
fn overlap_by_pairs(scene: &Scene) -> Option<String> {
    let scale = |b: &Aabb| {
        b.min
            .iter()
            .chain(b.max.iter())
            .fold(1.0f64, |m, x| m.max(x.abs()))
    };
    for (i, a) in scene.blocks.iter().enumerate() {
        for b in &scene.blocks[i + 1..] {
            if let Some(overlap) = a.aabb().intersection(&b.aabb()) {
                let tol = 1e-9 * scale(&a.aabb()).max(scale(&b.aabb()));
                if overlap.extent().iter().all(|x| *x > tol) {
                    return Some(format!("block \"{}\": overlaps block \"{}\"", a.id, b.id));
                }
            }
        }
    }
    None
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    /// Blocks on a coarse grid with random sizes (touching, apart, overlapping by whole cells
    /// or by a hair, some very wide): validation refuses the pair the pairwise loop finds first,
    /// and no pair when it finds none.
    #[test]
    fn block_overlaps_equal_the_pairwise_loop(
        list in proptest::collection::vec(
            ((0u8..12, 0u8..3, 0u8..12), (1u8..4, 1u8..3, 1u8..4), 0u8..6), 1..30),
    ) {
        let mut values = Vec::new();
        for (k, &((x, y, z), (w, h, d), shape)) in list.iter().enumerate() {
            let mut min = [x as f64, y as f64 * 3.0, z as f64];
            let mut max = [min[0] + w as f64, min[1] + h as f64 * 3.0, min[2] + d as f64];
            match shape {
                // Into the next cell by a hair: below the tolerance, or just above it.
                1 => max[0] += 1e-12,
                2 => max[0] += 1e-7,
                // Very wide: the window must reach back over it.
                3 => min[0] -= 40.0,
                _ => {}
            }
            values.push(block(&format!("b{k}"), min, max, &[]));
        }
        let scene: Scene = serde_json::from_value(blocks(values)).unwrap();
        let got = scene
            .validate()
            .err()
            .map(|e| e.to_string())
            .filter(|e| e.contains("overlaps block"));
        prop_assert_eq!(got, overlap_by_pairs(&scene));
    }
}
