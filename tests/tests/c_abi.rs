//! The C ABI end to end: bake the Cornell box, compile `client/capi/examples/apply.c` with the
//! system C compiler against the `liblightfarm` shared library cargo built for this test, run it
//! on the bundle and two lights, and check that its checksums equal the ones the Rust client
//! computes through `Runtime::apply` on the same direct light, both at their default (all bounces);
//! then that the example's engine path (unshadowed direct light it computes itself from the
//! layout queries, through the lightmap atlas) matches the client's centre-sampled direct light
//! without occluders, applied the same way, and that its surfaces and atlas are the bundle's;
//! and that its moved light, relit through the one-light path (reach and direct light there,
//! `lf_runtime_light_direct`, bit-identical to `lf_runtime_direct_in_spans` on its spans; then
//! `lf_runtime_apply_delta_in_spans`), agrees with relighting everything, and moved back in
//! `LF_BOUNCES_FEEDBACK` settles (`lf_runtime_feedback_due`) to the first answer; and, on
//! `ball_corridor` (a dynamic object, so a probe volume), that the probe field it fills from
//! the light leaving the texels and its irradiance at a point, the placed object's own light
//! and its bounces, and the change of direct light its shadow makes when it moves
//! (`lf_runtime_shadow_change`) are the Rust client's.
//!
//! The library is found beside this test binary: `lightfarm-client-capi` is a dev-dependency
//! of this crate, so cargo builds its cdylib into `target/<profile>/deps/` (and, when the capi
//! package itself is built, copies it to `target/<profile>/`); the newest of the two is linked
//! with an rpath, so the example runs without `LD_LIBRARY_PATH`.

use std::path::{Path, PathBuf};
use std::process::Command;

use lightfarm_client::{
    direct_from_point_lights, direct_from_point_lights_averaged, frame_occluders,
    occluders_with_poses, Atlas, Bounces, IndirectLight, Light, Method, ObjectLight, Occluders,
    Runtime, ShadowChange,
};
use lightfarm_proto::lights::{LightKind, LightSet, Pose};
use lightfarm_proto::scene::Transport;
use lightfarm_tests::*;

/// Point lights as `[x, y, z, r, g, b]`: the Cornell box's lamp and a dimmer orange one.
const LIGHTS: [[f32; 6]; 2] = [
    [2.75, 5.2, 2.75, 10.0, 10.0, 10.0],
    [1.2, 4.0, 4.4, 3.0, 1.5, 0.5],
];

/// A fresh scratch directory for this process.
fn scratch_dir() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lf-c-abi-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The directory holding the newest `liblightfarm` shared library cargo built for this test.
fn library_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let deps = exe.parent().unwrap();
    let name = format!(
        "{}lightfarm{}",
        std::env::consts::DLL_PREFIX,
        std::env::consts::DLL_SUFFIX
    );
    [deps, deps.parent().unwrap()]
        .into_iter()
        .filter_map(|dir| {
            let modified = std::fs::metadata(dir.join(&name)).ok()?.modified().ok()?;
            Some((modified, dir.to_path_buf()))
        })
        .max()
        .map(|(_, dir)| dir)
        .unwrap_or_else(|| {
            panic!(
                "no {name} beside {} or in its parent: build with `cargo test` so the \
                 lightfarm-client-capi dev-dependency is built",
                deps.display()
            )
        })
}

/// Compiles the C example into `dir`; returns the executable.
fn compile_example(dir: &Path) -> PathBuf {
    let capi = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../client/capi");
    let lib_dir = library_dir();
    let exe = dir.join("apply");
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let output = Command::new(&cc)
        .args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-I"])
        .arg(capi.join("include"))
        .arg(capi.join("examples/apply.c"))
        .arg("-L")
        .arg(&lib_dir)
        .arg("-llightfarm")
        .arg("-lm")
        .arg(format!("-Wl,-rpath,{}", lib_dir.display()))
        .arg("-o")
        .arg(&exe)
        .output()
        .unwrap_or_else(|e| panic!("cannot run the C compiler `{cc}`: {e}"));
    assert!(
        output.status.success(),
        "apply.c does not compile:\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    exe
}

/// A command running the compiled example against the library it was linked with: cargo puts
/// `target/<profile>` on `LD_LIBRARY_PATH` for tests, which outranks the rpath, so a stale copy
/// there would otherwise be loaded instead.
fn example(exe: &Path) -> Command {
    let mut command = Command::new(exe);
    command.env("LD_LIBRARY_PATH", library_dir());
    command
}

/// Runs the compiled example with `args` and returns its (one-line) output, failing the test
/// with its stderr when it fails; `what` names the run.
fn run_example(exe: &Path, args: &[&std::ffi::OsStr], what: &str) -> String {
    let output = example(exe).args(args).output().unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "apply failed on {what}: {}{stdout}",
        String::from_utf8_lossy(&output.stderr)
    );
    let line = stdout.lines().next().expect("one output line").to_string();
    eprintln!("C example, {what}: {line}");
    line
}

/// The value of `key=` in the example's output line.
fn field<'a>(line: &'a str, key: &str) -> &'a str {
    line.split_whitespace()
        .find_map(|kv| kv.strip_prefix(key)?.strip_prefix('='))
        .unwrap_or_else(|| panic!("no {key}= in {line:?}"))
}

fn number(line: &str, key: &str) -> f64 {
    field(line, key).parse().unwrap()
}

fn assert_close(label: &str, c: f64, rust: f64) {
    let rel = (c - rust).abs() / rust.abs().max(f64::MIN_POSITIVE);
    assert!(
        rel < 1e-5,
        "{label}: C {c:e}, Rust {rust:e} (relative {rel:e})"
    );
}

#[test]
fn c_example_matches_the_rust_client() {
    let dir = scratch_dir();
    let (scene, _) = load_scene("cornell", 8, 256);
    let (bytes, _) = bake_scene(&scene, &scene_dir("cornell"), Transport::Lightfield, false);
    let bundle_path = dir.join("cornell.lfb");
    std::fs::write(&bundle_path, &bytes).unwrap();
    let lights_path = dir.join("lights.txt");
    let text: String = LIGHTS
        .iter()
        .map(|l| format!("{} {} {} {} {} {}\n", l[0], l[1], l[2], l[3], l[4], l[5]))
        .collect();
    std::fs::write(&lights_path, format!("# x y z r g b\n{text}\n")).unwrap();

    // The Rust client on the same input: the C side parses the same f32 values.
    let bundle = lightfarm_client::decode(&bytes).unwrap();
    let occluders = Occluders::from_layout(&bundle.layout);
    let lights: Vec<Light> = LIGHTS
        .iter()
        .map(|l| Light {
            kind: LightKind::Point,
            position: [l[0], l[1], l[2]].map(f64::from),
            intensity: [l[3], l[4], l[5]].map(f64::from),
        })
        .collect();
    let direct = direct_from_point_lights_averaged(
        &bundle.layout,
        &occluders,
        &lights,
        lightfarm::LF_DIRECT_SAMPLES_PER_EDGE,
    );
    // The engine path: centre sampling, no shadows.
    let unshadowed = lightfarm_proto::bundle::Layout {
        rects: vec![],
        triangles: vec![],
        ..bundle.layout.clone()
    };
    let engine_direct =
        direct_from_point_lights(&unshadowed, &Occluders::from_layout(&unshadowed), &lights);
    let atlas = Atlas::from_layout_with(&bundle.layout, &bundle.surface_atlases);
    let surfaces = bundle.layout.surfaces.clone();
    let mut runtime = Runtime::try_new(bundle).unwrap();
    assert!(runtime.has_drt(), "the Cornell box has clutter");
    // The C runtime sums all bounces unless told otherwise, like the Rust client's default.
    let mut indirect = IndirectLight::default();
    let applied = runtime
        .apply(Method::Drt, Bounces::default(), &direct, &mut indirect)
        .unwrap();
    assert!(
        applied.bounces > 1,
        "all bounces take more than one application"
    );
    let sum = |v: &[[f32; 3]]| v.iter().flatten().map(|&x| x as f64).sum::<f64>();
    let max = indirect
        .radiance
        .iter()
        .flatten()
        .fold(f64::NEG_INFINITY, |m, &x| m.max(x as f64));

    let exe = compile_example(&dir);
    let line = run_example(
        &exe,
        &[bundle_path.as_os_str(), lights_path.as_os_str()],
        "cornell",
    );
    let line = line.as_str();
    assert_eq!(
        field(line, "texels").parse::<usize>().unwrap(),
        runtime.n_texels()
    );
    assert_eq!(field(line, "method"), "drt");
    assert_eq!(
        field(line, "applications").parse::<u32>().unwrap(),
        applied.bounces
    );
    assert!(sum(&indirect.radiance) > 0.0 && max > 0.0);
    assert_close(
        "checksum",
        number(line, "checksum"),
        sum(&indirect.radiance),
    );
    assert_close("max", number(line, "max"), max);
    assert_close(
        "direct_checksum",
        number(line, "direct_checksum"),
        sum(&direct.radiance),
    );

    assert_eq!(
        field(line, "surfaces").parse::<usize>().unwrap(),
        surfaces.len()
    );
    assert_eq!(field(line, "first_surface"), surfaces[0].name);
    assert_eq!(
        field(line, "atlas"),
        format!("{}x{}", atlas.width, atlas.height)
    );
    let mut engine_indirect = IndirectLight::default();
    runtime
        .apply(
            Method::Drt,
            Bounces::default(),
            &engine_direct,
            &mut engine_indirect,
        )
        .unwrap();
    assert!(sum(&engine_direct.radiance) > 0.0);
    assert_close(
        "engine_direct_checksum",
        number(line, "engine_direct_checksum"),
        sum(&engine_direct.radiance),
    );
    assert_close(
        "engine_checksum",
        number(line, "engine_checksum"),
        sum(&engine_indirect.radiance),
    );
    assert_eq!(
        field(line, "probes"),
        "0",
        "the Cornell box has no dynamic object"
    );
    // Light 0 moved and relit by its change (reach, direct light there, apply_delta) against
    // relighting everything, both at all bounces to the default tolerance 1e-3.
    assert!(field(line, "moved_spans").parse::<usize>().unwrap() >= 1);
    let moved_error = number(line, "moved_error");
    assert!(
        moved_error < 3e-3,
        "moved light relit by its change: {moved_error:.2e}"
    );
    // The one-call reach and direct light (shadow rays against the reached room's occluders
    // only) gave what direct light on the same spans against the whole level gives.
    assert_eq!(field(line, "light_direct_same"), "1", "{line}");
    // Moved back in LF_BOUNCES_FEEDBACK: one call with the change, then calls with no span
    // until nothing is due; all bounces of the first lights within the tolerance's reach
    // (both ends are `Converged` to 1e-3).
    let calls: usize = field(line, "feedback_calls").parse().unwrap();
    assert!((1..1000).contains(&calls), "{calls} calls to settle");
    let feedback_error = number(line, "feedback_error");
    assert!(
        feedback_error < 3e-3,
        "moved back by feedback: {feedback_error:.2e} after {calls} calls"
    );
    // The runtime's estimate of the light still to arrive: some after the change, at most the
    // tolerance (1e-3) once nothing is due.
    let (lag, left) = (number(line, "feedback_lag"), number(line, "feedback_left"));
    assert!(
        lag > 0.0 && left <= 1e-3 && left < lag,
        "estimated lag {lag:.2e}, left {left:.2e}"
    );

    // A level with a dynamic object, placed as its light set places it: the probe volume
    // through the C ABI (fed direct plus indirect light at all bounces) and the object's own
    // light and its bounces are the Rust client's.
    let (scene, _) = load_scene("ball_corridor", 8, 256);
    let (ball_bytes, _) = bake_scene(
        &scene,
        &scene_dir("ball_corridor"),
        Transport::Lightfield,
        false,
    );
    let ball_path = dir.join("ball_corridor.lfb");
    std::fs::write(&ball_path, &ball_bytes).unwrap();
    let ball_lights = dir.join("ball_lights.txt");
    std::fs::write(&ball_lights, "2.6 2.2 1.3 12 12 12\n").unwrap();
    let bundle = lightfarm_client::decode(&ball_bytes).unwrap();
    let occluders = Occluders::from_layout(&bundle.layout);
    let light = [Light {
        kind: LightKind::Point,
        position: [2.6f32, 2.2, 1.3].map(f64::from),
        intensity: [12.0; 3],
    }];
    // The scene's pose, in the f32 C passes.
    let pose: Pose = {
        let set: LightSet = serde_json::from_str(
            &std::fs::read_to_string(scene_dir("ball_corridor").join("lights.json")).unwrap(),
        )
        .unwrap();
        let mut p = set.poses[0].clone();
        p.translation = p.translation.map(|x| x as f32 as f64);
        p.rotation = p.rotation.map(|x| x as f32 as f64);
        p
    };
    let t = pose.translation;
    let q = pose.rotation;
    let pose_arg = format!(
        "{},{},{},{},{},{},{},{}",
        pose.id,
        t[0] as f32,
        t[1] as f32,
        t[2] as f32,
        q[0] as f32,
        q[1] as f32,
        q[2] as f32,
        q[3] as f32
    );
    let posed = occluders_with_poses(&occluders, &bundle, std::slice::from_ref(&pose));
    let direct = direct_from_point_lights_averaged(
        &bundle.layout,
        frame_occluders(&occluders, posed.as_ref()),
        &light,
        lightfarm::LF_DIRECT_SAMPLES_PER_EDGE,
    );
    let (p0, n0) = (bundle.layout.positions[0], bundle.layout.normals[0]);
    let mut runtime = Runtime::try_new(bundle.clone()).unwrap();
    let method = if runtime.has_drt() {
        Method::Drt
    } else {
        Method::Mrt
    };
    let mut indirect = IndirectLight::default();
    runtime
        .apply(method, Bounces::default(), &direct, &mut indirect)
        .unwrap();
    let leaving = lightfarm_server::evaluate::leaving_light(&direct, &indirect);
    let mut probes = lightfarm_client::ProbeField::default();
    runtime.apply_probes(&leaving, &mut probes).unwrap();
    let at: [f32; 3] = std::array::from_fn(|c| p0[c] + 0.25 * n0[c]);
    let e = lightfarm_client::irradiance_at(runtime.probe_volume().unwrap(), &probes, at, n0);
    let mut objects = ObjectLight::new(&bundle).unwrap();
    let poses = [pose];
    objects
        .update(&bundle, &probes, true, &occluders, &light, &poses)
        .unwrap();
    let mut bounced = IndirectLight {
        radiance: vec![[0.0; 3]; bundle.layout.n_texels()],
    };
    objects
        .bounce(&mut runtime, method, Bounces::default(), &mut bounced)
        .unwrap();
    let args = [
        ball_path.as_os_str(),
        ball_lights.as_os_str(),
        pose_arg.as_ref(),
    ];
    let line = run_example(&exe, &args, "ball_corridor");
    let line = line.as_str();
    assert_eq!(
        field(line, "probes").parse::<usize>().unwrap(),
        probes.n_probes()
    );
    assert!(probes.n_probes() > 0);
    let field_sum: f64 = probes.as_slice().iter().map(|&v| v as f64).sum();
    assert!(field_sum > 0.0);
    assert_close("probe_checksum", number(line, "probe_checksum"), field_sum);
    let e_sum = e.iter().map(|&v| v as f64).sum::<f64>();
    assert!(e_sum > 0.0, "light reaches the probes above texel 0");
    assert_close("probe_irradiance", number(line, "probe_irradiance"), e_sum);
    let spans: usize = field(line, "object_spans").parse().unwrap();
    assert_eq!(spans, objects.spans().len());
    assert!(spans > 0, "the ball lights the floor around it");
    let object_sum = sum(&objects.light().radiance);
    assert!(object_sum != 0.0);
    assert_close(
        "object_checksum",
        number(line, "object_checksum"),
        object_sum,
    );
    let bounce_sum = sum(&bounced.radiance);
    assert!(bounce_sum != 0.0);
    assert_close(
        "object_bounce_checksum",
        number(line, "object_bounce_checksum"),
        bounce_sum,
    );
    // The ball moved 0.1 m along x (in f32, as C adds it): the client's change of its shadow.
    let mut moved = poses.clone();
    moved[0].translation[0] = (poses[0].translation[0] as f32 + 0.1f32) as f64;
    let samples = lightfarm::LF_DIRECT_SAMPLES_PER_EDGE;
    let mut shadows = ShadowChange::new(&bundle, &occluders, &light, samples, &poses);
    shadows.update(&bundle, &occluders, &moved).unwrap();
    let spans: usize = field(line, "shadow_spans").parse().unwrap();
    assert_eq!(spans, shadows.spans().len());
    assert!(spans > 0, "the ball's shadow moves");
    let shadow_sum = sum(&shadows.change().radiance);
    assert!(shadow_sum != 0.0);
    assert_close(
        "shadow_checksum",
        number(line, "shadow_checksum"),
        shadow_sum,
    );

    // A file that is not a bundle: exit status 1 and the library's reason on stderr.
    let garbage = dir.join("garbage.lfb");
    std::fs::write(&garbage, b"not a bundle at all").unwrap();
    let output = example(&exe)
        .arg(&garbage)
        .arg(&lights_path)
        .output()
        .unwrap();
    assert_eq!(output.status.code(), Some(1));
    assert_eq!(
        String::from_utf8_lossy(&output.stderr).trim(),
        "error: lf_runtime_new: cannot load bundle: not a lightfarm bundle (bad magic)"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
