//! Shared helpers for the end-to-end tests in `tests/tests/`: load the example scenes with
//! test-sized settings, bake them, apply bundles through the client and compare with the
//! reference solver; start the test server and learn its address.

use std::path::{Path, PathBuf};

use lightfarm_client::{Bounces, Method};
use lightfarm_proto::bounces::BounceCount;
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::{compare, Comparison, ResultFile};
use lightfarm_proto::scene::{Scene, Transport};
use lightfarm_server::bake::progress::NoProgress;
use lightfarm_server::bake::reference::{reference, ReferenceSettings};
use lightfarm_server::bake::scene::geometry::Geometry;
use lightfarm_server::bake::{bake, BakeOptions, BakeReport};
use lightfarm_server::evaluate::evaluate;

/// `scenes/<name>` in the repository.
pub fn scene_dir(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../scenes")
        .join(name)
}

/// An example scene and its lights, with settings scaled down for tests.
pub fn load_scene(name: &str, texels_per_face: u32, rays_per_texel: u32) -> (Scene, LightSet) {
    let dir = scene_dir(name);
    let mut scene =
        Scene::from_json(&std::fs::read_to_string(dir.join("scene.json")).unwrap()).unwrap();
    scene.settings.texels_per_face = texels_per_face;
    scene.settings.rays_per_texel = rays_per_texel;
    let lights =
        LightSet::from_json(&std::fs::read_to_string(dir.join("lights.json")).unwrap()).unwrap();
    (scene, lights)
}

/// A 4 × 3 × 4 m room (one red wall) with a crate on the floor: the DRT and SH responses
/// tests' scene, at `texels` per face and `rays` per texel.
pub fn room_with_box(texels: u32, rays: u32) -> Scene {
    let mut scene = Scene::from_json(
        r#"{ "format": "lightfarm.scene/1", "name": "box on a floor",
             "blocks": [ { "id": "room", "min": [0,0,0], "max": [4,3,4], "albedo": [0.7,0.7,0.7],
                           "face_albedo": { "-x": [0.7, 0.2, 0.2] } } ],
             "clutter": [ { "id": "crate", "box": { "min": [1.5,0,1.5], "max": [2.5,1.2,2.5] }, "albedo": [0.2,0.6,0.3] } ] }"#,
    )
    .unwrap();
    scene.settings.texels_per_face = texels;
    scene.settings.rays_per_texel = rays;
    scene
}

/// Bakes with the given transport and an optional dense operator: the bundle as the bake
/// made it (`.encode()` stores it losslessly, in f32, for the few tests about what the
/// operators hold before a codec rounds them; [`bake_scene`] stores it as a bake does).
pub fn bake_bundle(
    scene: &Scene,
    dir: &Path,
    transport: Transport,
    full: bool,
) -> (lightfarm_proto::bundle::Bundle, BakeReport) {
    let options = BakeOptions {
        cache: None,
        full,
        transport: Some(transport),
    };
    bake(scene, dir, &options, &NoProgress).expect("bake")
}

/// Bakes with the given transport and an optional dense operator, stored as `lightfarm bake`
/// stores it ([`stored`]: the scene's codecs), so that tests see what a game receives.
pub fn bake_scene(
    scene: &Scene,
    dir: &Path,
    transport: Transport,
    full: bool,
) -> (Vec<u8>, BakeReport) {
    let (bundle, report) = bake_bundle(scene, dir, transport, full);
    (stored(scene, &bundle), report)
}

/// `bundle`'s bytes as `lightfarm bake` writes them for `scene`: its codecs (8 bits where a
/// matrix fits the scene's codec budget), so a bake done here by other means compares with
/// [`bake_scene`]'s bytes.
pub fn stored(scene: &Scene, bundle: &lightfarm_proto::bundle::Bundle) -> Vec<u8> {
    let options = lightfarm_server::bake::pipeline::encoding::encode_options(&scene.settings, None);
    bundle.encode_with(&options).0
}

/// Applies a bundle as a game would.
pub fn apply(bundle: &[u8], lights: &LightSet, method: Method) -> ResultFile {
    let bundle = lightfarm_client::decode(bundle).expect("decode");
    evaluate(bundle, lights, method, Bounces::One).expect("evaluate")
}

/// The reference solution of a scene.
pub fn reference_of(scene: &Scene, dir: &Path, lights: &LightSet, rays: u32) -> ResultFile {
    let mut g = Geometry::from_scene(scene, dir).unwrap();
    g.add_posed_dynamic(scene, dir, &lights.poses).unwrap();
    let settings = ReferenceSettings::new(rays, BounceCount::ONE, 1234);
    reference(&g, &lights.lights, &settings, &|_| {})
}

/// The one accuracy check every test uses: `ours` against `reference` within `tolerance`
/// (relative L2 over matched texels), with every value finite.
pub fn check_against_reference(
    label: &str,
    ours: &ResultFile,
    reference: &ResultFile,
    tolerance: f64,
) -> Comparison {
    assert!(
        ours.texels
            .iter()
            .all(|t| t.indirect.iter().chain(&t.direct).all(|x| x.is_finite())),
        "{label}: non-finite output"
    );
    let c = compare(ours, reference);
    eprintln!(
        "{label}: relative_l2={:.4} p95={:.4} matched={}",
        c.relative_l2, c.p95, c.matched
    );
    assert!(c.matched > 0, "{label}: no texels matched");
    assert!(
        c.relative_l2 <= tolerance,
        "{label}: relative L2 {:.4} exceeds {tolerance}",
        c.relative_l2
    );
    c
}

/// A scene of closed-off blocks `(id, min, max, open faces as JSON list items)` of one grey
/// albedo `rho`, at `texels_per_face`, `rays_per_texel` and `tolerance`.
pub fn grey_blocks(
    name: &str,
    blocks: &[(&str, [f64; 3], [f64; 3], &str)],
    rho: f64,
    (texels_per_face, rays_per_texel, tolerance): (u32, u32, f64),
) -> Scene {
    let blocks: Vec<String> = blocks
        .iter()
        .map(|(id, min, max, open)| {
            format!(
                r#"{{"id": "{id}", "min": {min:?}, "max": {max:?}, "open": [{open}],
                     "albedo": [{rho}, {rho}, {rho}]}}"#
            )
        })
        .collect();
    Scene::from_json(&format!(
        r#"{{"format": "lightfarm.scene/1", "name": "{name}",
            "settings": {{"texels_per_face": {texels_per_face}, "rays_per_texel": {rays_per_texel},
                          "tolerance": {tolerance}}},
            "blocks": [{}]}}"#,
        blocks.join(",")
    ))
    .expect("scene")
}

/// `Σ π L_ind A` (red channel) over a bundle's texels, each with its own area (a closed grey
/// level's indirect flux).
pub fn indirect_flux(bundle: &lightfarm_client::Bundle, result: &ResultFile) -> f64 {
    result
        .by_layout_texel(&bundle.layout)
        .iter()
        .zip(&bundle.layout.texel_size)
        .map(|(t, size)| {
            let t = t.expect("every texel has a record");
            std::f64::consts::PI * t.indirect[0] * size[0] as f64 * size[1] as f64
        })
        .sum()
}

/// Asserts a closed level's indirect `flux` within `within` (relative) of the geometric series'
/// `want`, printing both under `label`.
pub fn check_flux_against(label: &str, flux: f64, want: f64, within: f64) {
    eprintln!(
        "{label}: flux {flux:.5} vs {want:.5} ({:+.2}%)",
        100.0 * (flux / want - 1.0)
    );
    assert!(
        (flux - want).abs() <= within * want,
        "{label}: indirect flux {flux} vs the geometric series {want}"
    );
}

/// Largest `indirect / (albedo × max direct seen)` over texels and channels: ≤ 1 for any
/// one-bounce solution (a perfect reflector cannot return more than the brightest direct light).
pub fn energy_ratio(result: &ResultFile) -> f64 {
    let max_direct = result
        .texels
        .iter()
        .flat_map(|t| t.direct)
        .fold(0.0, f64::max);
    let mut worst: f64 = 0.0;
    for t in &result.texels {
        for c in 0..3 {
            if t.albedo[c] > 0.0 && max_direct > 0.0 {
                worst = worst.max(t.indirect[c] / (t.albedo[c] * max_direct));
            }
        }
    }
    worst
}

/// Starts `command` (the test server, `tests/bin/test_server.rs`, with its arguments) with
/// stdout piped and waits for its first line, `lightfarm: listening on ADDR`: the running
/// child and ADDR.
pub fn spawn_listening(command: &mut std::process::Command) -> (std::process::Child, String) {
    use std::io::{BufRead, BufReader};
    let mut child = command
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::inherit())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .trim()
        .strip_prefix("lightfarm: listening on ")
        .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
        .to_string();
    (child, addr)
}

/// Checks a bundle's light reach against lighting every texel, for each light alone at each
/// of `positions`: the direct light on the reached spans, traced against the reached rooms'
/// occluders only (`ReachDirect::light`), is bit-identical to the whole-layout direct light
/// there, and every texel left out is exactly dark in it; and every position's light at once
/// lit light by light where each reaches (`ReachDirect::all_lights`) is bit-identical to
/// lighting every texel with them all. Returns the texels reached, the texels lit and the
/// positions whose shadow rays met fewer occluders than the level's, summed over the positions
/// (`samples` per texel edge).
pub fn check_light_reach(
    bundle: &lightfarm_proto::bundle::Bundle,
    light: &lightfarm_client::Light,
    positions: &[[f64; 3]],
    samples: u32,
) -> (usize, usize, usize) {
    use lightfarm_client::{
        direct_from_point_lights_adaptive, direct_scale, Occluders, ReachDirect,
    };
    let layout = &bundle.layout;
    let occluders = Occluders::from_layout(layout);
    let scale = direct_scale(layout, &occluders);
    let mut reach = ReachDirect::new(bundle, &occluders).expect("the bundle has rooms");
    let (mut reached, mut lit, mut cut) = (0, 0, 0);
    let mut spans = Vec::new();
    let mut every = Vec::new();
    for p in positions {
        let mut l = light.clone();
        l.position = *p;
        every.push(l.clone());
        let lights = std::slice::from_ref(&l);
        let whole = direct_from_point_lights_adaptive(layout, &occluders, lights, samples);
        let mut part = vec![[f32::NAN; 3]; layout.n_texels()];
        reach.light(
            layout, &occluders, &l, samples, scale, &mut spans, &mut part,
        );
        cut += usize::from(reach.occluders_traced() < occluders.len());
        let mut inside = vec![false; layout.n_texels()];
        for s in &spans {
            inside[s.texels.clone()].fill(true);
        }
        for (t, (w, q)) in whole.radiance.iter().zip(&part).enumerate() {
            if inside[t] {
                assert_eq!(
                    w.map(f32::to_bits),
                    q.map(f32::to_bits),
                    "texel {t}, light at {p:?}"
                );
            } else {
                assert_eq!(
                    *w,
                    [0.0; 3],
                    "texel {t} ({}) is lit by the light at {p:?} but out of its reach",
                    layout
                        .surfaces
                        .iter()
                        .find(|s| (s.texel_offset as usize
                            ..(s.texel_offset + s.texel_count) as usize)
                            .contains(&t))
                        .map_or("?", |s| s.name.as_str())
                );
                assert!(q[0].is_nan(), "texel {t} outside the spans was written");
            }
            lit += usize::from(*w != [0.0; 3]);
        }
        reached += inside.iter().filter(|&&i| i).count();
    }
    let whole = direct_from_point_lights_adaptive(layout, &occluders, &every, samples);
    let by_reach = reach.all_lights(layout, &occluders, &every, samples, scale);
    for (t, (w, r)) in whole.radiance.iter().zip(&by_reach.radiance).enumerate() {
        assert_eq!(
            w.map(f32::to_bits),
            r.map(f32::to_bits),
            "texel {t}: every light at once against light by light where each reaches"
        );
    }
    (reached, lit, cut)
}
