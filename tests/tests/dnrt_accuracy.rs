//! DNRT against brute force on `scenes/ball_corridor`: the change a posed red ball makes to
//! indirect light (reference with the ball minus reference without) is reproduced by the
//! bundle's DNRT grid applied through `eval` (with poses minus without), on the texels within
//! two ball radii of its centre; the ball's direct shadow matches the reference's and its
//! bounced light the reference's change far from the ball. At all bounces the light the ball
//! takes away bounces on through the room as in an all-bounce reference. Measured figures for other settings are in
//! `tests/data/dnrt_accuracy.md`.

use lightfarm_client::{Bounces, Method};
use lightfarm_proto::bounces::BounceCount;
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::ResultFile;
use lightfarm_proto::scene::Transport;
use lightfarm_server::bake::reference::{reference, ReferenceSettings};
use lightfarm_server::bake::scene::geometry::Geometry;
use lightfarm_tests::*;

/// Per channel, (DNRT delta, reference delta) of the texels whose distance from `centre` is
/// kept by `keep`.
fn deltas_where(
    ours_with: &ResultFile,
    ours_without: &ResultFile,
    ref_with: &ResultFile,
    ref_without: &ResultFile,
    centre: [f64; 3],
    keep: impl Fn(f64) -> bool,
) -> Vec<([f64; 3], [f64; 3])> {
    let key = |t: &lightfarm_proto::result::TexelRecord| (t.surface.clone(), t.index);
    let index = |r: &ResultFile| -> std::collections::HashMap<_, [f64; 3]> {
        r.texels.iter().map(|t| (key(t), t.indirect)).collect()
    };
    let (ow, oo, ro) = (index(ours_with), index(ours_without), index(ref_without));
    ref_with
        .texels
        .iter()
        .filter(|t| {
            let d: f64 = (0..3).map(|k| (t.position[k] - centre[k]).powi(2)).sum();
            keep(d.sqrt())
        })
        .map(|t| {
            let k = key(t);
            (
                std::array::from_fn(|c| ow[&k][c] - oo[&k][c]),
                std::array::from_fn(|c| t.indirect[c] - ro[&k][c]),
            )
        })
        .collect()
}

/// `scenes/ball_corridor` at `texels` per face and `rays` per texel, its ball's DNRT grid at
/// `resolution`³ points of `grid_rays` rays, baked with lightfield transport: the scene, its
/// lights (the ball posed), its directory, the bundle and the bake's report.
fn ball_corridor(
    texels: u32,
    rays: u32,
    resolution: u32,
    grid_rays: u32,
) -> (
    lightfarm_proto::scene::Scene,
    LightSet,
    std::path::PathBuf,
    Vec<u8>,
    lightfarm_server::bake::BakeReport,
) {
    let (mut scene, lights) = load_scene("ball_corridor", texels, rays);
    scene.settings.dnrt.resolution = resolution;
    scene.settings.dnrt.rays = grid_rays;
    let dir = scene_dir("ball_corridor");
    let (bundle, report) = bake_scene(&scene, &dir, Transport::Lightfield, false);
    (scene, lights, dir, bundle, report)
}

#[test]
fn dnrt_reproduces_what_the_posed_ball_changes_near_it() {
    let (scene, lights, dir, bundle, report) = ball_corridor(16, 256, 16, 128);
    assert_eq!(report.dnrt.len(), 1);
    assert_eq!(
        report.dnrt[0].2,
        16 * 16 * 16 * 4 * 9,
        "u8: one byte per value (t_j in R, G, B and k_j)"
    );
    let without = LightSet {
        poses: vec![],
        ..lights.clone()
    };
    let ours_with = apply(&bundle, &lights, Method::Mrt);
    let ours_without = apply(&bundle, &without, Method::Mrt);
    let ref_with = reference_of(&scene, &dir, &lights, 4096);
    let ref_without = reference_of(&scene, &dir, &without, 4096);
    let pose = &lights.poses[0];
    let radius = 0.35;
    let near = deltas_where(
        &ours_with,
        &ours_without,
        &ref_with,
        &ref_without,
        pose.translation,
        |d| d <= 2.0 * radius,
    );
    assert!(near.len() >= 20, "{} texels near the ball", near.len());
    let (mut num, mut den) = (0.0, 0.0);
    for (ours, truth) in &near {
        for c in 0..3 {
            num += (ours[c] - truth[c]).powi(2);
            den += truth[c].powi(2);
        }
    }
    let rel = (num / den).sqrt();
    eprintln!(
        "DNRT delta near the ball: relative L2 {rel:.4} over {} texels",
        near.len()
    );
    // Measured 0.178 here (16³, 9 SH, 128 rays per point, reference 4096 rays), 0.245 before
    // eval shadowed direct light with the posed ball (the shadow's bounced light was missing
    // near it; 0.212–0.216 then at 256 rays against a 16384-ray reference in
    // tests/data/dnrt_accuracy.md). The margin covers seed and platform changes of the Monte
    // Carlo runs.
    assert!(rel < 0.22, "relative L2 {rel}");
    // The ball darkens its surroundings (occlusion wins) and tints them red: less is taken
    // from red than from green, in the reference and in DNRT.
    let mean = |ours: bool, c: usize| {
        let pick = |x: &([f64; 3], [f64; 3])| if ours { x.0[c] } else { x.1[c] };
        near.iter().map(pick).sum::<f64>() / near.len() as f64
    };
    let (ours_r, ours_g) = (mean(true, 0), mean(true, 1));
    let (ref_r, ref_g) = (mean(false, 0), mean(false, 1));
    eprintln!(
        "mean delta (r, g): DNRT ({ours_r:.4}, {ours_g:.4}), reference ({ref_r:.4}, {ref_g:.4})"
    );
    // The occlusion's strength: DNRT with the hidden radiance (Appendix B.2) plus the ball's
    // direct shadow take away 0.97 of what the reference loses here (DNRT alone took 0.84; the
    // rest was the shadow's bounced light).
    let ratio = ours_g / ref_g;
    assert!(
        (0.85..1.05).contains(&ratio),
        "DNRT / reference mean delta (green) {ratio}"
    );
    assert!(ref_g < 0.0 && ours_g < 0.0, "ref {ref_g}, ours {ours_g}");
    assert!(
        ref_r > ref_g && ours_r > ours_g,
        "ref {ref_r} vs {ref_g}, ours {ours_r} vs {ours_g}"
    );
    // Far from the ball (beyond its outer volume) DNRT adds nothing: what changes there is
    // the bounced light of the ball's direct shadow (eval shadows the operators' direct light
    // with the posed ball), which follows the reference's change.
    let outer = scene.settings.dnrt.outer_extent * radius * 3f64.sqrt();
    let far = deltas_where(
        &ours_with,
        &ours_without,
        &ref_with,
        &ref_without,
        pose.translation,
        |d| d > outer,
    );
    let (mut num, mut den, mut ours_sum, mut ref_sum) = (0.0, 0.0, 0.0, 0.0);
    for (ours, truth) in &far {
        for c in 0..3 {
            num += (ours[c] - truth[c]).powi(2);
            den += truth[c].powi(2);
            ours_sum += ours[c];
            ref_sum += truth[c];
        }
    }
    let far_rel = (num / den).sqrt();
    eprintln!(
        "far from the ball ({} texels): change relative L2 {far_rel:.4}, summed change ours \
         {ours_sum:.4} reference {ref_sum:.4}",
        far.len()
    );
    // The ball's direct shadow: every texel the reference leaves without direct light that has
    // it without the ball is dark in ours too, and direct light matches the reference.
    // Measured: 0.60 and 0.73 of the reference's summed change (the rest is the ball blocking
    // light between far surfaces, which DNRT's outer volume leaves out; 4096 reference rays
    // make the far change noisy). Without the shadow ours was 0 there.
    assert!(far_rel < 0.75, "far change relative L2 {far_rel}");
    let share = ours_sum / ref_sum;
    assert!((0.55..1.1).contains(&share), "far change share {share}");
    let direct_of = |r: &ResultFile| -> Vec<f64> { r.texels.iter().map(|t| t.direct[1]).collect() };
    let key = |r: &ResultFile| -> Vec<(String, u32)> {
        r.texels
            .iter()
            .map(|t| (t.surface.clone(), t.index))
            .collect()
    };
    assert_eq!(key(&ours_with), key(&ref_with));
    let (ow, oo, rw) = (
        direct_of(&ours_with),
        direct_of(&ours_without),
        direct_of(&ref_with),
    );
    let shadowed: Vec<usize> = (0..rw.len())
        .filter(|&i| rw[i] == 0.0 && oo[i] > 0.0)
        .collect();
    assert!(
        shadowed.len() >= 5,
        "{} texels in the ball's shadow",
        shadowed.len()
    );
    assert!(shadowed.iter().all(|&i| ow[i] == 0.0));
    let direct_rel = (ow
        .iter()
        .zip(&rw)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        / rw.iter().map(|b| b * b).sum::<f64>())
    .sqrt();
    eprintln!(
        "direct light with the ball: relative L2 {direct_rel:.2e}, {} texels in its shadow",
        shadowed.len()
    );
    assert!(direct_rel < 1e-6, "direct light relative L2 {direct_rel}");
    assert!(ours_with
        .texels
        .iter()
        .all(|t| t.indirect.iter().all(|x| x.is_finite())));
}

/// Summed indirect light (all channels) of a result.
fn total_indirect(r: &ResultFile) -> f64 {
    r.texels.iter().flat_map(|t| t.indirect).sum()
}

#[test]
fn at_all_bounces_the_light_the_ball_takes_away_bounces_through_the_room() {
    let (scene, lights, dir, bundle, _) = ball_corridor(8, 256, 16, 128);
    let without = LightSet {
        poses: vec![],
        ..lights.clone()
    };
    let all = |set: &LightSet| {
        let decoded = lightfarm_client::decode(&bundle).expect("decode");
        lightfarm_server::evaluate::evaluate(decoded, set, Method::Mrt, Bounces::default())
            .expect("evaluate")
    };
    let reference_all = |set: &LightSet| {
        let mut g = Geometry::from_scene(&scene, &dir).unwrap();
        g.add_posed_dynamic(&scene, &dir, &set.poses).unwrap();
        let settings = ReferenceSettings::new(2048, BounceCount::All, 1234);
        reference(&g, &set.lights, &settings, &|_| {})
    };
    let (ours_with, ours_without) = (all(&lights), all(&without));
    let (ref_with, ref_without) = (reference_all(&lights), reference_all(&without));
    let ours = total_indirect(&ours_with) - total_indirect(&ours_without);
    let truth = total_indirect(&ref_with) - total_indirect(&ref_without);
    // Far from the ball, where DNRT itself adds nothing, the change is the bounced light of
    // what the ball did near it.
    let pose = &lights.poses[0];
    let far = deltas_where(
        &ours_with,
        &ours_without,
        &ref_with,
        &ref_without,
        pose.translation,
        |d| d > 2.0,
    )
    .into_iter()
    .fold((0.0, 0.0), |(o, r), (a, b)| {
        (o + a.iter().sum::<f64>(), r + b.iter().sum::<f64>())
    });
    eprintln!(
        "all bounces, the ball's summed change: ours {ours:.3}, reference {truth:.3} ({:.3}); \
         beyond 2 m ours {:.3}, reference {:.3} ({:.3})",
        ours / truth,
        far.0,
        far.1,
        far.0 / far.1
    );
    // Measured 0.953 and 0.908; with the change's bounces switched off, 0.382 and 0.190 (the
    // ball's direct shadow alone bounces on).
    assert!(truth < 0.0 && ours < 0.0, "ours {ours}, reference {truth}");
    assert!(
        (0.85..1.15).contains(&(ours / truth)),
        "summed {}",
        ours / truth
    );
    assert!(
        (0.75..1.2).contains(&(far.0 / far.1)),
        "beyond 2 m {}",
        far.0 / far.1
    );
}

#[test]
fn a_pose_without_a_grid_is_an_error_naming_it() {
    let (_, lights, _, bundle, _) = ball_corridor(4, 32, 4, 16);
    let mut wrong = lights.clone();
    wrong.poses[0].id = "blue_cube".into();
    let bundle = lightfarm_client::decode(&bundle).expect("decode");
    let err = lightfarm_server::evaluate::evaluate(
        bundle,
        &wrong,
        Method::Mrt,
        lightfarm_client::Bounces::One,
    )
    .unwrap_err();
    assert!(err.to_string().contains("\"blue_cube\""), "{err}");
}
