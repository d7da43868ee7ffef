//! SH responses for normal-mapped surfaces (`settings.sh_responses`, bundle section `sh`):
//! consistency with the scalar DRT output at the geometric normal, agreement with a brute-force
//! SH gather and with brute-force irradiance at a tilted normal, determinism across thread
//! counts, and nothing changing when the setting is off. Measured values are in
//! `tests/data/sh_responses.md`.

use std::f64::consts::PI;

use lightfarm_client::{
    direct_from_point_lights_averaged, Bounces, IndirectLight, Method, Occluders, Runtime, ShLight,
};
use lightfarm_proto::bundle::{Bundle, DeltaSource, EncodeOptions};
use lightfarm_proto::codec::{CodecPolicy, MatrixCodec};
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::scene::{Scene, Transport};
use lightfarm_proto::sh::{irradiance, irradiance_weights, SH_COEFFS};
use lightfarm_server::bake::reference::{reference_incident_sh, reference_irradiance};
use lightfarm_server::bake::scene::geometry::Geometry;
use lightfarm_server::bake::tracer::Tracer;
use lightfarm_server::evaluate::DIRECT_SAMPLES_PER_EDGE;
use lightfarm_tests::*;

fn room_with_box(texels: u32, rays: u32) -> Scene {
    let mut scene = lightfarm_tests::room_with_box(texels, rays);
    scene.settings.sh_responses = true;
    scene
}

fn box_lights() -> LightSet {
    LightSet::from_json(r#"{ "lights": [ { "kind": "point", "position": [0.8, 2.4, 1.0], "intensity": [6, 6, 6] } ] }"#).unwrap()
}

/// Bakes (lightfield transport, no dense operator) and decodes: stored as a bake stores it, or
/// `lossless` (f32, for the tests of what the section holds before a codec rounds it).
fn bake_decoded(scene: &Scene, dir: &std::path::Path, lossless: bool) -> (Vec<u8>, Bundle) {
    let bytes = if lossless {
        bake_bundle(scene, dir, Transport::Lightfield, false)
            .0
            .encode()
    } else {
        bake_scene(scene, dir, Transport::Lightfield, false).0
    };
    let bundle = Bundle::decode(&bytes).expect("decode");
    (bytes, bundle)
}

/// The scalar DRT output and the SH responses for the same direct light (as `eval` feeds it).
fn apply_both(bundle: Bundle, lights: &LightSet) -> (IndirectLight, ShLight, Vec<bool>) {
    let occluders = Occluders::from_layout(&bundle.layout);
    let direct = direct_from_point_lights_averaged(
        &bundle.layout,
        &occluders,
        &lights.lights,
        DIRECT_SAMPLES_PER_EDGE,
    );
    let mut lit = vec![true; bundle.layout.n_texels()];
    for &t in &bundle.drt.as_ref().expect("scene has clutter").buried {
        lit[t as usize] = false;
    }
    let mut runtime = Runtime::new(bundle);
    let mut scalar = IndirectLight::default();
    runtime
        .apply(Method::Drt, Bounces::One, &direct, &mut scalar)
        .unwrap();
    let mut sh = ShLight::default();
    runtime.apply_sh(&direct, &mut sh).unwrap();
    // A second call gives the same bits (scratch is refilled, not accumulated).
    let mut again = ShLight::default();
    runtime.apply_sh(&direct, &mut again).unwrap();
    runtime.apply_sh(&direct, &mut again).unwrap();
    assert_eq!(sh, again, "apply_sh is not repeatable");
    (scalar, sh, lit)
}

/// `sqrt(Σ (a − b)² / Σ b²)` over pairs.
fn relative_l2(pairs: impl Iterator<Item = (f64, f64)>) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (a, b) in pairs {
        assert!(a.is_finite() && b.is_finite());
        num += (a - b) * (a - b);
        den += b * b;
    }
    (num / den).sqrt()
}

fn is_block(bundle: &Bundle, t: usize) -> bool {
    bundle
        .layout
        .surfaces
        .iter()
        .find(|s| (s.texel_offset as usize..(s.texel_offset + s.texel_count) as usize).contains(&t))
        .is_some_and(|s| s.name.starts_with("block:"))
}

/// The geometric normal tilted by `degrees` toward the next world axis (a normal map's normal).
fn tilted(n: [f32; 3], degrees: f64) -> [f64; 3] {
    let axis = (0..3).find(|k| n[*k] != 0.0).unwrap();
    let mut t = [0.0; 3];
    t[(axis + 1) % 3] = 1.0;
    let (c, s) = (degrees.to_radians().cos(), degrees.to_radians().sin());
    [0, 1, 2].map(|k| c * n[k] as f64 + s * t[k])
}

#[test]
fn sh_irradiance_at_the_geometric_normal_matches_scalar_drt_on_cornell() {
    let (mut scene, lights) = load_scene("cornell", 8, 1024);
    scene.settings.sh_responses = true;
    let (_, bundle) = bake_decoded(&scene, &scene_dir("cornell"), false);
    let layout = bundle.layout.clone();
    let blocks: Vec<bool> = (0..layout.n_texels())
        .map(|t| is_block(&bundle, t))
        .collect();
    let (scalar, sh, lit) = apply_both(bundle, &lights);
    let pairs = |want_block: bool| {
        let (layout, scalar, sh, lit, blocks) = (&layout, &scalar, &sh, &lit, &blocks);
        (0..layout.n_texels())
            .filter(move |t| lit[*t] && blocks[*t] == want_block)
            .flat_map(move |t| {
                let ours = sh.shade(t, layout.normals[t], layout.albedo[t]);
                (0..3).map(move |c| (ours[c] as f64, scalar.radiance[t][c] as f64))
            })
    };
    let block_error = relative_l2(pairs(true));
    let clutter_error = relative_l2(pairs(false));
    eprintln!("cornell T=8: SH at n vs scalar DRT: block texels {block_error:.4}, clutter texels {clutter_error:.4}");
    // SH order 2 over a hemisphere-clipped field and two independent 1024-ray estimators. On
    // clutter texels the scalar DRT gathers the exact direct light while the SH rows read the
    // blocks' implicit lights `L_imp b` (the paper's C_b, without the box's contact shadow on
    // the floor): that is most of the larger difference there (see the brute-force test).
    assert!(block_error < 0.06, "block texels {block_error}");
    assert!(clutter_error < 0.20, "clutter texels {clutter_error}");
}

#[test]
fn sh_matches_brute_force_and_shades_tilted_normals_on_a_box_on_a_floor() {
    let dir = scene_dir("cornell");
    let scene = room_with_box(8, 1024);
    let lights = box_lights();
    let (_, bundle) = bake_decoded(&scene, &dir, false);
    let layout = bundle.layout.clone();
    let blocks: Vec<bool> = (0..layout.n_texels())
        .map(|t| is_block(&bundle, t))
        .collect();
    let (scalar, sh, lit) = apply_both(bundle, &lights);

    let g = Geometry::from_scene(&scene, &dir).unwrap();
    let tracer = Tracer::new(g.primitives.clone(), g.scale());
    assert_eq!(g.texels.len(), layout.n_texels());
    let texels: Vec<usize> = (0..layout.n_texels()).filter(|t| lit[*t]).collect();
    let weights = irradiance_weights();
    let (mut coef, mut at_n, mut tilt, mut tilt_bf_sh) = (vec![], vec![], vec![], vec![]);
    // Per kind (block, clutter): E(n) of ours and of the scalar DRT (ρE/π undone) against
    // brute-force irradiance at n, to tell the SH path's error from the scalar one's.
    let mut split: [[Vec<(f64, f64)>; 2]; 2] = Default::default();
    for &t in &texels {
        let truth = reference_incident_sh(&g, &tracer, &lights.lights, t, 4096, 7);
        let n = layout.normals[t];
        let n64 = n.map(f64::from);
        let n_tilted = tilted(n, 30.0);
        let e_tilted = reference_irradiance(&g, &tracer, &lights.lights, t, n_tilted, 4096, 7);
        let ours_n = sh.irradiance(t, n);
        let ours_tilted = sh.irradiance(t, n_tilted.map(|x| x as f32));
        let e_n = reference_irradiance(&g, &tracer, &lights.lights, t, n64, 4096, 7);
        let kind = usize::from(!blocks[t]);
        for c in 0..3 {
            let rho = layout.albedo[t][c] as f64;
            split[kind][0].push((ours_n[c] as f64, e_n[c]));
            split[kind][1].push((PI * scalar.radiance[t][c] as f64 / rho, e_n[c]));
            for lm in 0..SH_COEFFS {
                // Irradiance-weighted coefficients (what shading reads).
                let w = weights[lm] / PI;
                coef.push((w * sh.coefficients[t][c][lm] as f64, w * truth[c][lm]));
            }
            at_n.push((ours_n[c] as f64, irradiance(&truth[c], n64)));
            tilt.push((ours_tilted[c] as f64, e_tilted[c]));
            tilt_bf_sh.push((irradiance(&truth[c], n_tilted), e_tilted[c]));
        }
    }
    let e_coef = relative_l2(coef.into_iter());
    let e_n = relative_l2(at_n.into_iter());
    let e_tilt = relative_l2(tilt.into_iter());
    let e_truncation = relative_l2(tilt_bf_sh.into_iter());
    eprintln!(
        "box on a floor T=8, {} lit texels: SH coefficients (irradiance-weighted) vs brute force {e_coef:.4}; \
         E(n) vs brute-force SH {e_n:.4}; E(n tilted 30°) vs brute-force irradiance {e_tilt:.4} \
         (brute-force SH itself: {e_truncation:.4}, the order-2 truncation)",
        texels.len()
    );
    let [[sh_block, drt_block], [sh_clutter, drt_clutter]] =
        split.map(|k| k.map(|v| relative_l2(v.into_iter())));
    eprintln!(
        "E(n) vs brute-force irradiance: block texels SH {sh_block:.4} (scalar DRT {drt_block:.4}), \
         clutter texels SH {sh_clutter:.4} (scalar DRT {drt_clutter:.4})"
    );
    assert!(e_coef < 0.10, "SH coefficients {e_coef}");
    assert!(e_n < 0.08, "irradiance at n {e_n}");
    assert!(e_tilt < 0.08, "irradiance at the tilted normal {e_tilt}");
    assert!(sh_block < 0.05, "block texels {sh_block}");
    assert!(sh_clutter < 0.11, "clutter texels {sh_clutter}");
}

#[test]
fn sh_bake_is_identical_at_one_and_two_threads() {
    let dir = scene_dir("cornell");
    let scene = room_with_box(4, 128);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| bake_scene(&scene, &dir, Transport::Lightfield, false).0)
    };
    let one = run(1);
    assert!(Bundle::decode(&one).unwrap().sh.is_some());
    assert!(one == run(2), "bundles differ between 1 and 2 threads");
}

#[test]
fn without_the_setting_there_is_no_sh_section_and_nothing_else_changes() {
    let dir = scene_dir("cornell");
    let on = room_with_box(4, 128);
    let mut off = on.clone();
    off.settings.sh_responses = false;
    // Off is the default and is not serialised (bake ids and canonical scenes stay the same).
    assert!(!lightfarm_proto::scene::Settings::default().sh_responses);
    assert!(!serde_json::to_string(&off.settings)
        .unwrap()
        .contains("sh_responses"));
    let (off_bytes, off_bundle) = bake_decoded(&off, &dir, true);
    let (on_bytes, mut on_bundle) = bake_decoded(&on, &dir, true);
    assert!(off_bundle.sh.is_none());
    let minor = |b: &[u8]| u16::from_le_bytes([b[10], b[11]]);
    // Every bundle carries the writer's minor version (a streamed prefix and the whole bundle
    // must share their header), with or without the section.
    let writer = lightfarm_proto::bundle::BUNDLE_MINOR;
    assert_eq!(minor(&off_bytes), writer);
    assert_eq!(minor(&on_bytes), writer);
    let (_, report) = off_bundle.encode_with(&EncodeOptions::default());
    assert!(report.sections.iter().all(|(name, _)| *name != "sh"));
    let (_, report) = on_bundle.encode_with(&EncodeOptions::default());
    assert!(report.sections.iter().any(|(name, _)| *name == "sh"));
    // Everything but the new section is byte-identical.
    on_bundle.sh = None;
    assert!(
        on_bundle.encode() == off_bytes,
        "the setting changed other sections"
    );
    // The client says what is missing.
    let mut runtime = Runtime::new(off_bundle);
    let direct = lightfarm_client::DirectLight {
        radiance: vec![[0.0; 3]; runtime.n_texels()],
    };
    assert!(!runtime.has_sh());
    assert_eq!(
        runtime.apply_sh(&direct, &mut ShLight::default()),
        Err(lightfarm_client::ApplyError::MissingSh)
    );
}

#[test]
fn sh_section_round_trips_in_every_codec_and_validation_names_the_problem() {
    let dir = scene_dir("cornell");
    let (bytes, bundle) = bake_decoded(&room_with_box(4, 128), &dir, true);
    let sh = bundle.sh.clone().unwrap();
    assert!(sh
        .entries
        .iter()
        .any(|e| matches!(e.source, DeltaSource::Clutter(_))));
    assert!(sh
        .entries
        .iter()
        .any(|e| matches!(e.source, DeltaSource::Block(_))));
    // f32 is lossless (the bundle was baked losslessly).
    assert_eq!(Bundle::decode(&bundle.encode()).unwrap(), bundle);
    assert_eq!(Bundle::decode(&bytes).unwrap(), bundle);
    for (codec, budget) in [(MatrixCodec::F16, 1e-3), (MatrixCodec::U8Columns, 0.05)] {
        let (coded, _) = bundle.encode_with(&EncodeOptions {
            codec: CodecPolicy::Fixed(codec),
            transport_codec: None,
            zstd_level: 3,
        });
        let back = Bundle::decode(&coded).unwrap().sh.unwrap();
        assert_eq!(back.entries.len(), sh.entries.len());
        for (a, b) in back.entries.iter().zip(&sh.entries) {
            assert_eq!((a.texels.clone(), a.source), (b.texels.clone(), b.source));
            for (ma, mb) in [(&a.y, &b.y), (&a.z, &b.z)] {
                let e = relative_l2(
                    ma.data
                        .iter()
                        .zip(&mb.data)
                        .map(|(x, y)| (*x as f64, *y as f64)),
                );
                assert!(e < budget, "{codec:?}: relative error {e}");
            }
        }
    }
    let expect_invalid = |edit: &dyn Fn(&mut Bundle), what: &str| {
        let mut b = bundle.clone();
        edit(&mut b);
        let err = b.validate().expect_err(what).to_string();
        assert!(err.contains("sh: entry"), "{what}: {err}");
        assert!(Bundle::decode(&b.encode()).is_err(), "{what}: decoded");
    };
    expect_invalid(
        &|b| b.sh.as_mut().unwrap().entries[0].texels.reverse(),
        "texels descending",
    );
    expect_invalid(
        &|b| b.sh.as_mut().unwrap().entries[0].source = DeltaSource::Clutter(99),
        "missing source",
    );
    expect_invalid(
        &|b| {
            let e = &mut b.sh.as_mut().unwrap().entries[0];
            e.texels.pop();
        },
        "Y rows not 9 per texel",
    );
}
