//! A game-sized level in the test suite: `scripts/gen_level.py` writes a seeded 1,000-block
//! grid level (pillars, lights, a moving ball), baked here at small settings (2×2 texels per
//! face, 16 rays). The bake must finish and its bundle must relight through the client; a step
//! that is quadratic in the level's size (the DRT buried-texel test once was: 920 of a
//! 947 s bake at 1,000 blocks) makes this test take hours instead of seconds, so it cannot come
//! back unnoticed. A light's reach there (`LightReach`) is a neighbourhood, not the level, and
//! lights exactly what lighting every texel lights, and the blocks the bake keeps the f64
//! transport into for inpainting hold every buried texel. A lamp's change relit at all bounces
//! by the change writes a neighbourhood, within the tolerance; switched on by feedback it
//! settles within the tolerance, no call writing a tenth of the level. Also checks that the
//! generator is deterministic, and that a level of three storeys (`--storeys 3`) is one level
//! (every room reachable, shafts between the storeys) whose ground-floor lights light every
//! storey at all bounces, the upper ones less.

use std::path::{Path, PathBuf};
use std::process::Command;

use lightfarm_client::{
    direct_from_point_lights, Bounces, DirectLight, IndirectLight, Method, Occluders, Runtime,
};
use lightfarm_proto::scene::{Opening, Scene};
use lightfarm_server::bake::drt::inpaint::inpainting_targets;
use lightfarm_server::bake::scene::geometry::Geometry;
use lightfarm_server::evaluate::evaluate;
use lightfarm_tests::*;

/// Runs the generator into `dir` (2 texels per face, 16 rays); returns the scene text.
fn generate(dir: &Path, blocks: u32) -> String {
    generate_with(
        dir,
        &[
            "--blocks",
            &blocks.to_string(),
            "--texels",
            "2",
            "--rays",
            "16",
        ],
    )
}

/// Runs the generator into `dir` with `args`; returns the scene text.
fn generate_with(dir: &Path, args: &[&str]) -> String {
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scripts/gen_level.py");
    let output = Command::new("python3")
        .arg(&script)
        .arg(dir)
        .args(args)
        .output()
        .expect("python3 runs scripts/gen_level.py");
    assert!(
        output.status.success(),
        "gen_level.py failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    std::fs::read_to_string(dir.join("scene.json")).unwrap()
}

fn scratch(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lf-game-level-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn a_generated_thousand_block_level_bakes_and_relights() {
    let dir = scratch("bake");
    let text = generate(&dir, 1000);
    let scene = Scene::from_json(&text).expect("the generated level is a valid scene");
    assert_eq!(scene.blocks.len(), 1000);
    let pillars = scene.clutter.len();
    assert!(pillars > 20, "{pillars} pillars");

    let (bytes, report) = bake_scene(&scene, &dir, scene.settings.transport, false);
    assert_eq!(report.blocks, 1000);
    // The ball lists its room as the region it moves in: probes there only (`probe_volume:
    // auto`): 72, against 1,206 with the pillars' surroundings too and 43,506 over the whole
    // level.
    assert!(scene.dynamic.iter().all(|d| !d.regions.is_empty()));
    eprintln!("1,000 blocks: {} probes around the ball", report.probes);
    assert!(
        report.probes > 0 && report.probes < 400,
        "{} probes",
        report.probes
    );
    let bundle = lightfarm_client::decode(&bytes).unwrap();
    assert_eq!(bundle.drt.as_ref().map(|d| d.clutter.len()), Some(pillars));
    let n = bundle.layout.n_texels();
    assert_eq!(n, report.texels);

    // The bake keeps the f64 transport for DRT's inpainting only into blocks where a texel may
    // be buried, decided before any ray: every buried block texel must lie in one of them.
    let geometry = Geometry::from_scene(&scene, &dir).unwrap();
    let targets = inpainting_targets(&scene, &scene.openings().unwrap(), &geometry);
    let buried_blocks: Vec<usize> = bundle
        .drt
        .as_ref()
        .unwrap()
        .buried
        .iter()
        .filter_map(|&x| {
            geometry
                .block_texels
                .iter()
                .position(|r| r.contains(&(x as usize)))
        })
        .collect();
    let kept = targets.iter().filter(|t| **t).count();
    eprintln!(
        "1,000 blocks: {} buried block texels in {} blocks; the transport is kept into {kept}",
        buried_blocks.len(),
        buried_blocks
            .iter()
            .collect::<std::collections::BTreeSet<_>>()
            .len()
    );
    assert!(!buried_blocks.is_empty());
    assert!(buried_blocks.iter().all(|&b| targets[b]));
    assert!(kept < 1000, "every block kept");

    // Direct light of one lamp's worth on every 7th texel: enough to reach the whole level
    // through its bounces, without the client's direct-light pass over 160 lights.
    let direct = DirectLight {
        radiance: (0..n)
            .map(|t| {
                if t % 7 == 0 {
                    [1.0, 0.8, 0.6]
                } else {
                    [0.0; 3]
                }
            })
            .collect(),
    };
    // One light's reach: exact (checked against lighting every texel) and a neighbourhood:
    // each of 24 lights reaches under 5% of the level's texels (measured: at most 532 of
    // 16,840, the rooms along one long line of sight through aligned openings).
    let lights = lightfarm_proto::lights::LightSet::from_json(
        &std::fs::read_to_string(dir.join("lights.json")).unwrap(),
    )
    .unwrap();
    let (mut most, mut cut, mut checked) = (0, 0, 0);
    for light in lights
        .lights
        .iter()
        .step_by(lights.lights.len().div_ceil(24))
    {
        let (reached, lit, c) = check_light_reach(&bundle, light, &[light.position], 2);
        assert!(lit > 0, "the light at {:?} lights nothing", light.position);
        most = most.max(reached);
        cut += c;
        checked += 1;
    }
    eprintln!(
        "1,000 blocks: a light reaches at most {most} of {n} texels; {cut} of {checked} traced \
         against the reached rooms' occluders only"
    );
    assert!(most * 20 < n, "a light reaches {most} of {n} texels");
    assert!(
        cut == checked,
        "{cut} of {checked} lights cut the level's occluders"
    );

    // What `eval`, `export` and the service's evaluate and preview show: each light traced only
    // where it reaches, which at texel centres is the whole-level pass over every light and
    // texel to float rounding (the texel averages the operators read are checked the same way
    // in the client, `reach_direct`'s tests), and finishes in seconds at this size.
    let result = evaluate(bundle.clone(), &lights, Method::Drt, Bounces::One).unwrap();
    let occluders = Occluders::from_layout(&bundle.layout);
    let whole = direct_from_point_lights(&bundle.layout, &occluders, &lights.lights);
    let (mut lit, mut records) = (0, 0);
    for (t, record) in result.by_layout_texel(&bundle.layout).iter().enumerate() {
        let Some(record) = record else { continue };
        records += 1;
        lit += usize::from(whole.radiance[t] != [0.0; 3]);
        for c in 0..3 {
            let (got, want) = (record.direct[c], whole.radiance[t][c] as f64);
            assert!(
                (got - want).abs() <= 1e-6 * want.abs() + 1e-12,
                "texel {t}: eval's direct {got} against the whole-level pass's {want}"
            );
        }
    }
    eprintln!("1,000 blocks: eval's direct light at the centres of {records} texels, {lit} lit");
    assert_eq!(records, n, "eval reports every texel");
    assert!(lit * 4 > n, "{lit} of {n} texels lit");

    let mut runtime = Runtime::try_new(bundle).unwrap();
    let energy = |v: &IndirectLight| v.radiance.iter().flatten().map(|&x| x as f64).sum::<f64>();
    let mut one = IndirectLight::default();
    runtime
        .apply(Method::Drt, Bounces::One, &direct, &mut one)
        .unwrap();
    let mut all = IndirectLight::default();
    let applied = runtime
        .apply(Method::Drt, Bounces::default(), &direct, &mut all)
        .unwrap();
    let mut summed = IndirectLight::default();
    runtime
        .apply(Method::Drt, Bounces::Fixed(80), &direct, &mut summed)
        .unwrap();
    let (e1, e_all, e_sum) = (energy(&one), energy(&all), energy(&summed));
    eprintln!(
        "1,000 blocks: {n} texels, {pillars} pillars, one bounce {e1:.4e}, all {e_all:.4e} \
         ({} applications), 80 bounces summed {e_sum:.4e}",
        applied.bounces
    );
    assert!(e1 > 0.0 && e1.is_finite());
    // Albedo ≤ 0.79 in the generated level: every bounce keeps less than 0.79 of the last, so
    // all bounces hold at most 1 / (1 − 0.79) ≈ 4.8 × the first.
    assert!(
        e_all > 1.2 * e1 && e_all < 4.8 * e1,
        "all bounces {e_all} vs one {e1}"
    );
    assert!(
        (e_all - e_sum).abs() <= 3e-3 * e_sum,
        "Converged {e_all} vs 80 bounces {e_sum}"
    );

    // One lamp's change at all bounces, relit by the change bounce by bounce where its light
    // goes (`delta_bounces`): within the tolerance of the change's own light (80 exact bounces
    // of it), writing a neighbourhood of the level, not the level.
    let lamp = &lights.lights[lights.lights.len() / 2];
    let layout = runtime.bundle().layout.clone();
    let occluders = lightfarm_client::Occluders::from_layout(&layout);
    let change = lightfarm_client::direct_from_point_lights_adaptive(
        &layout,
        &occluders,
        std::slice::from_ref(lamp),
        2,
    );
    let mut exact = IndirectLight::default();
    runtime
        .apply(Method::Drt, Bounces::Fixed(80), &change, &mut exact)
        .unwrap();
    let l1 = |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.abs() as f64).sum::<f64>();
    for tolerance in [1e-2, 1e-3] {
        let mut by_change = IndirectLight {
            radiance: vec![[0.0; 3]; n],
        };
        let d = runtime
            .apply_delta(
                Method::Drt,
                Bounces::Converged { tolerance },
                &change,
                &mut by_change,
            )
            .unwrap();
        let written: usize = runtime
            .delta_written()
            .expect("answered bounce by bounce")
            .map(|r| r.len())
            .sum();
        let diff: Vec<[f32; 3]> = by_change
            .radiance
            .iter()
            .zip(&exact.radiance)
            .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
            .collect();
        let err = l1(&diff) / l1(&exact.radiance);
        eprintln!(
            "1,000 blocks: a lamp's change at all bounces (tolerance {tolerance}): {} bounces, \
             {} of {} block projections, {written} of {n} texels written, L1 error {err:.2e}",
            d.applied.bounces, d.blocks_projected, d.blocks_total
        );
        assert!(err <= 2.0 * tolerance as f64, "error {err}");
        assert!(written * 10 < n, "{written} of {n} texels written");
        assert!(
            d.blocks_projected * 20 < d.blocks_total,
            "{} of {} block projections",
            d.blocks_projected,
            d.blocks_total
        );
    }

    // The same lamp switched on by feedback (`delta_feedback`): every call one sparse bounce
    // of the change and of the light due, then calls with no change until nothing is due;
    // the answer then holds all bounces of the new light within the tolerance (relative to
    // the level's light, as `Converged`'s), and no call wrote a tenth of the level.
    let lit = DirectLight {
        radiance: direct
            .radiance
            .iter()
            .zip(&change.radiance)
            .map(|(a, b)| [a[0] + b[0], a[1] + b[1], a[2] + b[2]])
            .collect(),
    };
    let mut want = IndirectLight::default();
    runtime
        .apply(Method::Drt, Bounces::Fixed(80), &lit, &mut want)
        .unwrap();
    // The level's light before the lamp, as a game has it at load (the runtime's last
    // `apply` is the level's light feedback is judged against).
    let mut reference = IndirectLight::default();
    runtime
        .apply(Method::Drt, Bounces::Fixed(80), &direct, &mut reference)
        .unwrap();
    let tolerance = 1e-3;
    runtime.set_feedback_tolerance(tolerance).unwrap();
    let mut answer = reference.clone();
    let no_change = DirectLight {
        radiance: vec![[0.0; 3]; n],
    };
    let (mut calls, mut most) = (0, 0);
    loop {
        let delta = if calls == 0 { &change } else { &no_change };
        runtime
            .apply_delta(Method::Drt, Bounces::Feedback, delta, &mut answer)
            .unwrap();
        calls += 1;
        let written: usize = runtime.delta_written().unwrap().map(|r| r.len()).sum();
        most = most.max(written);
        if runtime.feedback_due() == 0 {
            break;
        }
        assert!(calls < 200, "still due after 200 calls");
    }
    let diff: Vec<[f32; 3]> = answer
        .radiance
        .iter()
        .zip(&want.radiance)
        .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
        .collect();
    let err = l1(&diff) / l1(&want.radiance);
    // The change's share of the level's light: the error against the change's own light.
    let change_light = l1(&exact.radiance) / l1(&want.radiance);
    eprintln!(
        "1,000 blocks: a lamp switched on by feedback settles in {calls} calls, at most {most} \
         of {n} texels written a call, L1 error {err:.2e} of the level's light ({:.2e} of \
         the lamp's; the lamp is {change_light:.2e} of the level's)",
        err / change_light
    );
    assert!(err <= 2.0 * tolerance as f64, "error {err}");
    // And near the tolerance of the lamp's own light (measured 2.9e-3 of it), where the
    // lamp's first bounce alone would miss about two thirds of it.
    assert!(
        err / change_light <= 10.0 * tolerance as f64,
        "error {} of the lamp's light",
        err / change_light
    );
    assert!(most * 10 < n, "{most} of {n} texels written in one call");
    assert!(calls >= 2, "settled in {calls} call");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_generator_is_deterministic() {
    let (a, b) = (scratch("a"), scratch("b"));
    let (ta, tb) = (generate(&a, 50), generate(&b, 50));
    assert_eq!(ta, tb);
    assert_eq!(
        std::fs::read(a.join("lights.json")).unwrap(),
        std::fs::read(b.join("lights.json")).unwrap()
    );
    let scene = Scene::from_json(&ta).unwrap();
    assert_eq!(scene.blocks.len(), 50);
    let _ = std::fs::remove_dir_all(&a);
    let _ = std::fs::remove_dir_all(&b);
}

/// The storey (0, 1, …) a point at height `y` lies on: storeys are 3 m high.
fn storey_of(y: f64) -> usize {
    (y / 3.0).floor().max(0.0) as usize
}

#[test]
fn a_generated_level_of_storeys_is_one_level_and_its_light_climbs_the_shafts() {
    let dir = scratch("storeys");
    let text = generate_with(
        &dir,
        &[
            "--blocks",
            "36",
            "--storeys",
            "3",
            "--stairs",
            "0.1",
            "--seed",
            "3",
            "--lights",
            "0.3",
            "--texels",
            "4",
            "--rays",
            "64",
            "--dynamic",
            "0",
        ],
    );
    let scene = Scene::from_json(&text).expect("the generated level is a valid scene");
    assert_eq!(scene.blocks.len(), 36);
    let storey = |b: usize| storey_of(scene.blocks[b].min[1] + 1.5);
    assert_eq!((0..36).map(storey).max(), Some(2));
    // Every room is reachable through openings, and each storey opens into the one above.
    let openings = scene.openings().expect("the openings match");
    let mut seen = vec![false; 36];
    let mut stack = vec![0];
    let mut shafts = [0usize; 2];
    seen[0] = true;
    while let Some(b) = stack.pop() {
        for o in openings[b].iter().flatten() {
            let Opening::Neighbour { block: n, .. } = *o else {
                continue;
            };
            if storey(n) == storey(b) + 1 {
                shafts[storey(b)] += 1;
            }
            if !std::mem::replace(&mut seen[n], true) {
                stack.push(n);
            }
        }
    }
    assert!(seen.iter().all(|&s| s), "a room no opening leads to");
    assert!(
        shafts.iter().all(|&n| n >= 1),
        "shafts between storeys: {shafts:?}"
    );

    // The ground floor's lights alone: at all bounces their light reaches every storey
    // through the shafts, and the upper storeys get less than the one they are on.
    let (bytes, _) = bake_scene(&scene, &dir, scene.settings.transport, false);
    let bundle = lightfarm_client::decode(&bytes).unwrap();
    let mut lights = lightfarm_proto::lights::LightSet::from_json(
        &std::fs::read_to_string(dir.join("lights.json")).unwrap(),
    )
    .unwrap();
    lights.lights.retain(|l| storey_of(l.position[1]) == 0);
    assert!(!lights.lights.is_empty());
    let all = Bounces::Converged { tolerance: 1e-3 };
    let result = evaluate(bundle.clone(), &lights, Method::Drt, all).unwrap();
    let mut per_storey = [0.0f64; 3];
    for r in result.by_layout_texel(&bundle.layout).iter().flatten() {
        // A texel a step off its surface lies in its own room (a floor at 3 m is storey 1's).
        let y = r.position[1] + 0.1 * r.normal[1];
        per_storey[storey_of(y).min(2)] += r.indirect.iter().sum::<f64>();
    }
    eprintln!("indirect light summed per storey, ground-floor lights: {per_storey:?}");
    assert!(per_storey.iter().all(|&e| e > 0.0 && e.is_finite()));
    assert!(per_storey[0] > per_storey[1] && per_storey[0] > per_storey[2]);
    let _ = std::fs::remove_dir_all(&dir);
}
