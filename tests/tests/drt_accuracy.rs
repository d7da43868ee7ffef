//! DRT against brute force: the delta a clutter box makes (reference with box minus reference
//! without) is reproduced by `drt − mrt`; clutter texels are lit; inpainting stays finite; DRT
//! beats MRT near clutter. Measured values are in `tests/data/drt_accuracy.md`.

use lightfarm_client::Method;
use lightfarm_proto::result::{compare, ResultFile};
use lightfarm_proto::scene::{Aabb, ClutterBasis, Scene, Transport};
use lightfarm_tests::*;

fn room_with_box(texels: u32, rays: u32, basis: ClutterBasis) -> Scene {
    let mut scene = lightfarm_tests::room_with_box(texels, rays);
    scene.settings.clutter_basis = basis;
    scene
}

fn lights() -> lightfarm_proto::lights::LightSet {
    lightfarm_proto::lights::LightSet::from_json(r#"{ "lights": [ { "kind": "point", "position": [0.8, 2.4, 1.0], "intensity": [6, 6, 6] } ] }"#).unwrap()
}

/// `a − b` texel by texel (records matched by surface and index; only those in both).
fn difference(a: &ResultFile, b: &ResultFile) -> ResultFile {
    let by_key: std::collections::HashMap<_, _> = b
        .texels
        .iter()
        .map(|t| ((t.surface.clone(), t.index), t))
        .collect();
    let mut out = ResultFile::default();
    for t in &a.texels {
        if let Some(o) = by_key.get(&(t.surface.clone(), t.index)) {
            let mut d = t.clone();
            for c in 0..3 {
                d.indirect[c] -= o.indirect[c];
            }
            out.texels.push(d);
        }
    }
    out
}

fn not_buried(r: &ResultFile, boxes: &[Aabb]) -> ResultFile {
    let mut out = r.clone();
    out.texels.retain(|t| {
        !t.surface.starts_with("block:")
            || !boxes.iter().any(|b| {
                (0..3).all(|k| t.position[k] >= b.min[k] - 1e-6 && t.position[k] <= b.max[k] + 1e-6)
            })
    });
    out
}

#[test]
fn delta_operators_reproduce_what_adding_the_box_changes() {
    let dir = scene_dir("cornell");
    let with_box = room_with_box(8, 1024, ClutterBasis::Prior);
    let mut without = with_box.clone();
    without.clutter.clear();
    let lights = lights();
    let boxes = [with_box.clutter[0].box_.unwrap()];
    let ref_with = not_buried(&reference_of(&with_box, &dir, &lights, 8192), &boxes);
    let ref_without = reference_of(&without, &dir, &lights, 8192);
    let (bundle, _) = bake_scene(&with_box, &dir, Transport::Lightfield, false);
    let (empty_bundle, _) = bake_scene(&without, &dir, Transport::Lightfield, false);
    let drt = apply(&bundle, &lights, Method::Drt);
    let mrt = apply(&bundle, &lights, Method::Mrt);
    // What MRT predicts for the empty room; the box changes direct light too (its shadow),
    // which enters through b, so the delta is taken against the empty room's prediction.
    let mrt_empty = apply(&empty_bundle, &lights, Method::Mrt);
    let blocks_only = |r: &ResultFile| {
        let mut r = not_buried(r, &boxes);
        r.texels.retain(|t| t.surface.starts_with("block:"));
        r
    };
    let delta_ref = difference(&blocks_only(&ref_with), &ref_without);
    let delta_drt = difference(&blocks_only(&drt), &mrt_empty);
    check_against_reference(
        "box delta (drt with − mrt without vs ref with − ref without)",
        &delta_drt,
        &delta_ref,
        0.12,
    );
    // DRT is closer to the reference than MRT on the scene texels.
    let e_drt = compare(&blocks_only(&drt), &ref_with).relative_l2;
    let e_mrt = compare(&blocks_only(&mrt), &ref_with).relative_l2;
    eprintln!("scene texels: mrt {e_mrt:.4}, drt {e_drt:.4}");
    assert!(
        e_drt < 0.5 * e_mrt,
        "DRT {e_drt} does not improve on MRT {e_mrt}"
    );
    // Clutter texels are lit by the scene.
    let mut clutter_only = drt.clone();
    clutter_only
        .texels
        .retain(|t| t.surface.starts_with("clutter:"));
    check_against_reference("clutter texels", &clutter_only, &ref_with, 0.25);
    assert!(
        energy_ratio(&drt) <= 1.05,
        "energy bound {}",
        energy_ratio(&drt)
    );
}

#[test]
fn face_constant_and_prior_bases_both_work() {
    let dir = scene_dir("cornell");
    let lights = lights();
    let reference = reference_of(
        &room_with_box(6, 512, ClutterBasis::Prior),
        &dir,
        &lights,
        4096,
    );
    for basis in [ClutterBasis::Prior, ClutterBasis::FaceConstant] {
        let scene = room_with_box(6, 512, basis);
        let (bundle, _) = bake_scene(&scene, &dir, Transport::Lightfield, false);
        let drt = not_buried(
            &apply(&bundle, &lights, Method::Drt),
            &[scene.clutter[0].box_.unwrap()],
        );
        check_against_reference(&format!("{basis:?}"), &drt, &reference, 0.2);
    }
}

#[test]
fn wholly_buried_texels_stay_finite_and_dark() {
    for mode in [
        lightfarm_proto::scene::SceneGather::Delta,
        lightfarm_proto::scene::SceneGather::Exact,
    ] {
        wholly_buried_floor_is_finite_and_dark(mode);
    }
}

fn wholly_buried_floor_is_finite_and_dark(mode: lightfarm_proto::scene::SceneGather) {
    // The crate covers the whole floor: floor texels have no valid neighbour to inpaint from.
    let mut scene = room_with_box(4, 256, ClutterBasis::Prior);
    scene.settings.scene_gather = mode;
    scene.clutter[0].box_ = Some(Aabb {
        min: [0.0, 0.0, 0.0],
        max: [4.0, 0.5, 4.0],
    });
    let dir = scene_dir("cornell");
    // Lossless: a buried texel is dark because its delta rows cancel its MRT light exactly
    // (`−U`), which is what this checks. Stored in 8 bits the two roundings leave a residue
    // (Delta: 6.3e-3 of the brightest visible texel, measured), under the crate where no one
    // sees it; zeroing it would need the runtime to drop those texels' MRT light (`replaced`),
    // which the coefficient-space solve does not model.
    let bundle = bake_bundle(&scene, &dir, Transport::Lightfield, false)
        .0
        .encode();
    let drt = apply(&bundle, &lights(), Method::Drt);
    assert!(drt
        .texels
        .iter()
        .all(|t| t.indirect.iter().all(|x| x.is_finite())));
    let max_visible = drt
        .texels
        .iter()
        .filter(|t| !t.surface.ends_with("/-y"))
        .flat_map(|t| t.indirect)
        .fold(0.0, f64::max);
    for t in drt.texels.iter().filter(|t| t.surface.ends_with("/-y")) {
        for x in t.indirect {
            assert!(
                x.abs() <= 1e-3 * max_visible,
                "{mode:?}: buried floor texel {} lit: {x}",
                t.index
            );
        }
    }
}

/// Props pressed together: a lid stacked on the crate, a box against its side, and two boxes
/// side by side in a corner. Where a face lies against another prop (the point 1 mm off it is
/// inside the other box) no light reaches it: ours is exactly 0 there, as the path tracer
/// finds. Before, such a face's rays started inside the other box and, where that box is flush
/// with a wall, could gather the wall's light (the corner pair's faces were lit). Every
/// clutter texel, pressed or not, then matches the reference.
#[test]
fn faces_pressed_against_another_prop_are_dark_like_the_reference() {
    let dir = scene_dir("cornell");
    let lights = lights();
    let mut scene = room_with_box(8, 1024, ClutterBasis::Prior);
    let crate_box = scene.clutter[0].box_.unwrap();
    let mut add = |id: &str, min: [f64; 3], max: [f64; 3]| {
        let mut c = scene.clutter[0].clone();
        c.id = id.into();
        c.box_ = Some(Aabb { min, max });
        scene.clutter.push(c);
    };
    add("lid", [1.7, 1.2, 1.7], [2.3, 1.8, 2.3]);
    add("side", [2.5, 0.0, 1.5], [3.0, 0.8, 2.0]);
    // Two boxes side by side in a corner, against both walls and the floor.
    add("corner_a", [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]);
    add("corner_b", [1.0, 0.0, 0.0], [1.5, 2.0, 0.5]);
    let boxes: Vec<(String, Aabb)> = scene
        .clutter
        .iter()
        .map(|c| (format!("clutter:{}", c.id), c.box_.unwrap()))
        .collect();
    assert_eq!(boxes[0].1, crate_box);
    let pressed = |t: &lightfarm_proto::result::TexelRecord| {
        let q: [f64; 3] = std::array::from_fn(|k| t.position[k] + 1e-3 * t.normal[k]);
        t.surface.starts_with("clutter:")
            && boxes.iter().any(|(name, b)| {
                !t.surface.starts_with(name.as_str())
                    && (0..3).all(|k| q[k] > b.min[k] && q[k] < b.max[k])
            })
    };
    let (bundle, report) = bake_scene(&scene, &dir, Transport::Lightfield, false);
    let drt = apply(&bundle, &lights, Method::Drt);
    let reference = reference_of(&scene, &dir, &lights, 8192);
    let exposed_mean = |r: &ResultFile| {
        let lit: Vec<f64> = r
            .texels
            .iter()
            .filter(|t| t.surface.starts_with("clutter:") && !pressed(t))
            .map(|t| t.indirect.iter().sum::<f64>())
            .collect();
        lit.iter().sum::<f64>() / lit.len() as f64
    };
    let n_pressed = drt.texels.iter().filter(|t| pressed(t)).count();
    // The lid covers 0.6 × 0.6 m of the crate's top, the side box 0.5 × 0.8 m of its +x face,
    // and the crate as much of each of theirs: at 8 texels per metre or finer, dozens of texels.
    assert!(n_pressed >= 40, "{n_pressed} pressed texels");
    assert!(report.drt.as_ref().unwrap().buried_clutter_texels >= n_pressed);
    for t in drt.texels.iter().filter(|t| pressed(t)) {
        assert_eq!(t.indirect, [0.0; 3], "{} {} lit", t.surface, t.index);
    }
    let reference_pressed: f64 = reference
        .texels
        .iter()
        .filter(|t| pressed(t))
        .map(|t| t.indirect.iter().sum::<f64>())
        .fold(0.0, f64::max);
    assert!(
        reference_pressed <= 1e-3 * exposed_mean(&reference),
        "the reference lights a pressed face: {reference_pressed}"
    );
    // measured 0.054 (0.054 before too: the pressed faces are few); bound 0.08
    let mut clutter = drt.clone();
    clutter.texels.retain(|t| t.surface.starts_with("clutter:"));
    check_against_reference(
        "clutter texels, props pressed together",
        &clutter,
        &reference,
        0.08,
    );
}

#[test]
fn drt_bake_is_identical_at_one_and_two_threads() {
    use lightfarm_proto::scene::SceneGather;
    let dir = scene_dir("cornell");
    for mode in [SceneGather::Delta, SceneGather::Exact] {
        let mut scene = room_with_box(4, 128, ClutterBasis::Prior);
        scene.settings.scene_gather = mode;
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| bake_scene(&scene, &dir, Transport::Traced, false).0)
        };
        assert!(run(1) == run(2), "{mode:?}");
    }
}

#[test]
fn probe_volume_shades_surfaces_close_to_the_reference_and_clutter_better_with_drt() {
    use lightfarm_client::{
        direct_from_point_lights_averaged, irradiance_at, Occluders, ProbeField, Runtime,
    };
    let dir = scene_dir("cornell");
    let mut scene = room_with_box(8, 1024, ClutterBasis::Prior);
    scene.settings.probe_spacing = 0.5;
    scene.settings.probe_volume = lightfarm_proto::scene::ProbeVolumeMode::Always;
    let lights = lights();
    let reference = not_buried(
        &reference_of(&scene, &dir, &lights, 8192),
        &[scene.clutter[0].box_.unwrap()],
    );
    let (bytes, _) = bake_scene(&scene, &dir, Transport::Lightfield, false);
    // Walls shaded from the probes (U_dyn) as a dynamic object touching them would be.
    let bundle = lightfarm_client::decode(&bytes).unwrap();
    let occluders = Occluders::from_layout(&bundle.layout);
    let direct = direct_from_point_lights_averaged(&bundle.layout, &occluders, &lights.lights, 4);
    let mut runtime = Runtime::try_new(bundle).unwrap();
    let mut field = ProbeField::default();
    runtime.apply_probes(&direct, &mut field).unwrap();
    let layout = &runtime.bundle().layout;
    let volume = runtime.probe_volume().unwrap();
    let mut shaded = ResultFile::default();
    for r in &reference.texels {
        if !r.surface.starts_with("block:") {
            continue;
        }
        let t = layout
            .surfaces
            .iter()
            .find(|s| s.name == r.surface)
            .unwrap()
            .texel_offset as usize
            + r.index as usize;
        let p = layout.positions[t];
        let n = layout.normals[t];
        let inside = [0, 1, 2].map(|k| p[k] + 0.25 * n[k]);
        let e = irradiance_at(volume, &field, inside, n);
        let mut rec = r.clone();
        rec.indirect = [0, 1, 2].map(|c| r.albedo[c] / std::f64::consts::PI * e[c] as f64);
        shaded.texels.push(rec);
    }
    check_against_reference("walls shaded from probes", &shaded, &reference, 0.35);
    // MRT shades clutter from the probes; DRT gathers: DRT must be clearly better there.
    let only_clutter = |r: ResultFile| ResultFile {
        texels: r
            .texels
            .into_iter()
            .filter(|t| t.surface.starts_with("clutter:"))
            .collect(),
    };
    let mrt = only_clutter(apply(&bytes, &lights, Method::Mrt));
    let drt = only_clutter(apply(&bytes, &lights, Method::Drt));
    let (e_mrt, e_drt) = (
        compare(&mrt, &reference).relative_l2,
        compare(&drt, &reference).relative_l2,
    );
    eprintln!("clutter texels: mrt (probes) {e_mrt:.4}, drt {e_drt:.4}");
    assert!(!mrt.texels.is_empty() && e_drt < 0.5 * e_mrt);
}

#[test]
fn exact_clutter_gather_holds_the_contact_shadow_the_implicit_one_misses() {
    use lightfarm_proto::scene::ClutterGather;
    let dir = scene_dir("cornell");
    let lights = lights();
    let base = room_with_box(8, 1024, ClutterBasis::Prior);
    let reference = reference_of(&base, &dir, &lights, 8192);
    let mut errors = Vec::new();
    for gather in [ClutterGather::Exact, ClutterGather::Implicit] {
        let mut scene = base.clone();
        scene.settings.clutter_gather = gather;
        let (bundle, _) = bake_scene(&scene, &dir, Transport::Lightfield, false);
        let mut drt = apply(&bundle, &lights, Method::Drt);
        drt.texels.retain(|t| t.surface.starts_with("clutter:"));
        errors.push(
            check_against_reference(
                &format!("clutter texels, {gather:?} gather"),
                &drt,
                &reference,
                0.25,
            )
            .relative_l2,
        );
    }
    assert!(
        errors[0] < 0.05 && errors[0] < 0.5 * errors[1],
        "exact {} vs implicit {}",
        errors[0],
        errors[1]
    );
}

#[test]
fn exact_scene_gather_replaces_mrt_near_the_box_and_matches_the_reference() {
    use lightfarm_proto::scene::SceneGather;
    let dir = scene_dir("cornell");
    let lights = lights();
    let base = room_with_box(8, 1024, ClutterBasis::Prior);
    let boxes = [base.clutter[0].box_.unwrap()];
    let reference = reference_of(&base, &dir, &lights, 8192);
    // Visible block texels within 1 m of the box (what `compare --near-clutter 1` scores).
    let near = |r: &ResultFile| {
        let mut r = not_buried(r, &boxes);
        r.texels.retain(|t| {
            let b = &boxes[0];
            let d2: f64 = (0..3)
                .map(|k| {
                    (b.min[k] - t.position[k])
                        .max(0.0)
                        .max(t.position[k] - b.max[k])
                        .powi(2)
                })
                .sum();
            t.surface.starts_with("block:") && d2 <= 1.0
        });
        r
    };
    let mut errors = Vec::new();
    for mode in [SceneGather::Delta, SceneGather::Exact] {
        let mut scene = base.clone();
        scene.settings.scene_gather = mode;
        let (bytes, report) = bake_scene(&scene, &dir, Transport::Lightfield, false);
        let gathered = report.drt.as_ref().unwrap().scene_texels_gathered;
        let replaced = lightfarm_client::decode(&bytes)
            .unwrap()
            .drt
            .unwrap()
            .replaced;
        assert_eq!(replaced.len(), gathered);
        assert_eq!(
            gathered == 0,
            mode == SceneGather::Delta,
            "{mode:?}: {gathered}"
        );
        let drt = apply(&bytes, &lights, Method::Drt);
        assert!(drt
            .texels
            .iter()
            .all(|t| t.indirect.iter().all(|x| x.is_finite())));
        assert!(
            energy_ratio(&drt) <= 1.05,
            "energy bound {}",
            energy_ratio(&drt)
        );
        errors.push(
            check_against_reference(
                &format!("block texels within 1 m of the box, {mode:?}"),
                &near(&drt),
                &reference,
                0.2,
            )
            .relative_l2,
        );
    }
    // The gather is exact to one bounce: only Monte Carlo noise separates it from the reference.
    assert!(
        errors[1] < 0.04 && errors[1] < errors[0],
        "exact {} vs delta {}",
        errors[1],
        errors[0]
    );
}
