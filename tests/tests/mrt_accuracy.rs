//! MRT against the brute-force reference on the example scenes (test-sized settings), energy
//! bounds, and inter-block light reaching blocks several openings away. Measured values at the
//! time of writing are in `tests/data/mrt_accuracy.md`; the bounds here leave room for noise.

use lightfarm_client::Method;
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::ResultFile;
use lightfarm_proto::scene::{Scene, Transport};
use lightfarm_tests::*;

/// The indirect light of the texels whose surface starts with `prefix`, summed over texels and
/// channels.
fn indirect_in(r: &ResultFile, prefix: &str) -> f64 {
    r.texels
        .iter()
        .filter(|t| t.surface.starts_with(prefix))
        .map(|t| t.indirect.iter().sum::<f64>())
        .sum()
}

#[test]
fn empty_cornell_box_mrt_and_full_match_the_reference() {
    let (mut scene, lights) = load_scene("cornell", 8, 512);
    scene.clutter.clear();
    let dir = scene_dir("cornell");
    let reference = reference_of(&scene, &dir, &lights, 4096);
    let (bundle, report) = bake_scene(&scene, &dir, Transport::Lightfield, true);
    assert_eq!(report.unique_shapes, 1);
    let mrt = apply(&bundle, &lights, Method::Mrt);
    let full = apply(&bundle, &lights, Method::Full);
    check_against_reference("cornell mrt", &mrt, &reference, 0.08);
    check_against_reference("cornell full", &full, &reference, 0.09);
    for (label, r) in [("reference", &reference), ("full", &full)] {
        assert!(
            energy_ratio(r) <= 1.0,
            "{label}: energy bound {}",
            energy_ratio(r)
        );
    }
    // The low-rank projection may ring slightly; it must stay close to the bound.
    assert!(
        energy_ratio(&mrt) <= 1.05,
        "mrt energy bound {}",
        energy_ratio(&mrt)
    );
}

#[test]
fn corridor_light_reaches_the_far_end_through_both_transports() {
    let (scene, lights) = load_scene("corridor", 8, 512);
    let dir = scene_dir("corridor");
    let reference = reference_of(&scene, &dir, &lights, 4096);
    let last = scene.blocks.last().unwrap().id.clone();
    // Two openings away from the lamp there is indirect light in the reference, and both
    // transports carry it there.
    let third = format!("block:{}/", scene.blocks[2].id);
    assert!(indirect_in(&reference, &third) > 0.0);
    for transport in [Transport::Lightfield, Transport::Traced] {
        let (bundle, _) = bake_scene(&scene, &dir, transport, false);
        let mrt = apply(&bundle, &lights, Method::Mrt);
        check_against_reference(&format!("corridor {transport:?}"), &mrt, &reference, 0.03);
        let ratio = indirect_in(&mrt, &third) / indirect_in(&reference, &third);
        assert!(
            (0.5..1.5).contains(&ratio),
            "{transport:?}: block 3 gets {ratio} of the reference's light"
        );
        assert!(indirect_in(&mrt, &format!("block:{last}/")) >= 0.0);
    }
}

#[test]
fn maze_mrt_matches_the_reference() {
    let (mut scene, lights) = load_scene("maze", 6, 256);
    scene.clutter.clear();
    let dir = scene_dir("maze");
    let reference = reference_of(&scene, &dir, &lights, 2048);
    for transport in [Transport::Lightfield, Transport::Traced] {
        let (bundle, report) = bake_scene(&scene, &dir, transport, false);
        assert!(
            report.unique_shapes < scene.blocks.len(),
            "identical blocks share shape operators"
        );
        let mrt = apply(&bundle, &lights, Method::Mrt);
        check_against_reference(&format!("maze {transport:?}"), &mrt, &reference, 0.05);
    }
}

/// A block open on five sides, a neighbour beyond each: its one closed face (the ceiling)
/// cannot see itself, so its own gather `F` is zero and, before its shape's rank kept what
/// leaves through the openings, it sent none of its lamp's light on (the floor below got
/// 0.42 of the reference's light in the generated level where this was found; this scene's
/// error was 0.36).
#[test]
fn a_block_open_on_five_sides_carries_its_light_to_every_neighbour() {
    let mut scene = Scene::from_json(
        r#"{ "format": "lightfarm.scene/1", "name": "five openings",
             "blocks": [
               { "id": "hub", "min": [0,3,0], "max": [6,6,5.5], "open": ["-x","+x","-y","-z","+z"], "albedo": [0.7,0.7,0.7] },
               { "id": "below", "min": [0,0,0], "max": [6,3,5.5], "open": ["+y"], "albedo": [0.6,0.6,0.6] },
               { "id": "west", "min": [-5.5,3,0], "max": [0,6,5.5], "open": ["+x"], "albedo": [0.7,0.65,0.6] },
               { "id": "east", "min": [6,3,0], "max": [9.5,6,5.5], "open": ["-x"], "albedo": [0.6,0.6,0.55] },
               { "id": "south", "min": [0,3,-3], "max": [6,6,0], "open": ["+z"], "albedo": [0.65,0.65,0.7] },
               { "id": "north", "min": [0,3,5.5], "max": [6,6,8.5], "open": ["-z"], "albedo": [0.6,0.6,0.65] } ] }"#,
    )
    .unwrap();
    scene.settings.texels_per_face = 8;
    scene.settings.rays_per_texel = 512;
    let lights = LightSet::from_json(
        r#"{ "lights": [ { "kind": "point", "position": [2.4, 4.9, 4.8], "intensity": [10, 10, 10] } ] }"#,
    )
    .unwrap();
    let dir = std::env::temp_dir();
    let reference = reference_of(&scene, &dir, &lights, 2048);
    let (bundle, _) = bake_scene(&scene, &dir, Transport::Traced, false);
    let mrt = apply(&bundle, &lights, Method::Mrt);
    check_against_reference("five openings", &mrt, &reference, 0.06);
    for block in ["below", "west", "east", "south", "north"] {
        let prefix = format!("block:{block}/");
        let ratio = indirect_in(&mrt, &prefix) / indirect_in(&reference, &prefix);
        eprintln!("{block}: {ratio:.3} of the reference's light");
        assert!(
            (0.9..1.1).contains(&ratio),
            "{block} gets {ratio} of the reference's light"
        );
    }
}
