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

/// Bakes with the given transport and an optional dense operator.
pub fn bake_scene(
    scene: &Scene,
    dir: &Path,
    transport: Transport,
    full: bool,
) -> (Vec<u8>, BakeReport) {
    let options = BakeOptions {
        cache: None,
        full,
        transport: Some(transport),
    };
    let (bundle, report) = bake(scene, dir, &options, &NoProgress).expect("bake");
    (bundle.encode(), report)
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
