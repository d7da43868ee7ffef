//! MRT against the brute-force reference on the example scenes (test-sized settings), energy
//! bounds, and inter-block light reaching blocks several openings away. Measured values at the
//! time of writing are in `tests/data/mrt_accuracy.md`; the bounds here leave room for noise.

use lightfarm_client::Method;
use lightfarm_proto::scene::Transport;
use lightfarm_tests::*;

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
    let energy_in = |r: &lightfarm_proto::result::ResultFile, prefix: &str| -> f64 {
        r.texels
            .iter()
            .filter(|t| t.surface.starts_with(prefix))
            .map(|t| t.indirect.iter().sum::<f64>())
            .sum()
    };
    // Two openings away from the lamp there is indirect light in the reference, and both
    // transports carry it there.
    let third = format!("block:{}/", scene.blocks[2].id);
    assert!(energy_in(&reference, &third) > 0.0);
    for transport in [Transport::Lightfield, Transport::Traced] {
        let (bundle, _) = bake_scene(&scene, &dir, transport, false);
        let mrt = apply(&bundle, &lights, Method::Mrt);
        check_against_reference(&format!("corridor {transport:?}"), &mrt, &reference, 0.03);
        let ratio = energy_in(&mrt, &third) / energy_in(&reference, &third);
        assert!(
            (0.5..1.5).contains(&ratio),
            "{transport:?}: block 3 gets {ratio} of the reference's light"
        );
        assert!(energy_in(&mrt, &format!("block:{last}/")) >= 0.0);
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
