//! The CLI contract other tools depend on: `bake`, `eval`, `reference`, `compare`, `schema`,
//! `inspect` (a report whose reader has left is no error), `serve` (up with its stdout's reader
//! gone), `frame-time --update one-light` (both ways, or the update alone), run as processes
//! on a small scene.

use std::path::{Path, PathBuf};
use std::process::Command;

fn lightfarm() -> Command {
    Command::new(env!("CARGO_BIN_EXE_lightfarm"))
}

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().expect("run lightfarm");
    assert!(
        out.status.success(),
        "{:?} failed: {}",
        cmd,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// A directory of the test `name`'s own (tests run in parallel and remove theirs at the end;
/// one shared directory let a test's clean-up delete another's files mid-run).
fn workdir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lf-cli-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn write_scene(dir: &Path) -> (PathBuf, PathBuf) {
    let scene = dir.join("scene.json");
    std::fs::write(
        &scene,
        r#"{ "format": "lightfarm.scene/1", "name": "two rooms",
             "settings": { "texels_per_face": 4, "rays_per_texel": 128, "tolerance": 0.01 },
             "blocks": [ { "id": "a", "min": [0,0,0], "max": [3,2.5,3], "open": ["+x"], "albedo": [0.7,0.7,0.7] },
                         { "id": "b", "min": [3,0,0], "max": [5,2.5,3], "open": ["-x"], "albedo": [0.6,0.5,0.4],
                           "face_albedo": { "-y": [0.2, 0.6, 0.2] } } ],
             "clutter": [ { "id": "crate", "box": { "min": [1,0,1], "max": [1.5,0.5,1.5] }, "albedo": [0.5,0.5,0.5] } ] }"#,
    )
    .unwrap();
    let lights = dir.join("lights.json");
    std::fs::write(&lights, r#"{ "lights": [ { "kind": "point", "position": [1.5, 2.0, 1.5], "intensity": [4, 4, 4] } ], "poses": [] }"#).unwrap();
    (scene, lights)
}

#[test]
fn bake_eval_reference_compare_round_trip() {
    let dir = workdir("round-trip");
    let (scene, lights) = write_scene(&dir);
    let bundle = dir.join("out.lfb");
    run(lightfarm()
        .args(["bake"])
        .arg(&scene)
        .arg("-o")
        .arg(&bundle)
        .arg("--cache")
        .arg(dir.join("cache"))
        .arg("--full"));
    assert!(bundle.exists());
    for method in ["mrt", "full"] {
        let result = dir.join(format!("{method}.json"));
        run(lightfarm()
            .arg("eval")
            .arg(&bundle)
            .arg("--lights")
            .arg(&lights)
            .args(["--method", method, "-o"])
            .arg(&result));
        let parsed: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&result).unwrap()).unwrap();
        let first = &parsed["texels"][0];
        for field in [
            "surface", "index", "position", "normal", "albedo", "direct", "indirect",
        ] {
            assert!(!first[field].is_null(), "RESULT.json texel lacks {field}");
        }
        assert_eq!(first["surface"], "block:a/-x");
    }
    let reference = dir.join("ref.json");
    run(lightfarm()
        .arg("reference")
        .arg(&scene)
        .arg("--lights")
        .arg(&lights)
        .args(["--rays", "1024", "-o"])
        .arg(&reference));
    let out = run(lightfarm()
        .arg("compare")
        .arg(dir.join("mrt.json"))
        .arg(&reference));
    let last = out.lines().last().unwrap();
    assert!(
        last.starts_with("relative_l2=") && last.contains(" p95="),
        "{last}"
    );
    let rel: f64 = last
        .trim_start_matches("relative_l2=")
        .split(' ')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(rel.is_finite() && rel < 1.0, "{rel}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_scene_is_refused_with_the_offending_field() {
    let dir = workdir("bad");
    let scene = dir.join("scene.json");
    std::fs::write(&scene, r#"{ "format": "lightfarm.scene/1", "name": "x", "blocks": [ { "id": "a", "min": [0,3,0], "max": [4,0,4], "albedo": [0.5,0.5,0.5] } ] }"#).unwrap();
    let out = lightfarm()
        .arg("bake")
        .arg(&scene)
        .arg("-o")
        .arg(dir.join("x.lfb"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(r#"block "a": max.y (0) <= min.y (3)"#),
        "{err}"
    );
    assert!(
        !dir.join("x.lfb").exists(),
        "nothing written for a refused scene"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn schema_describes_the_scene_format() {
    let out = run(lightfarm().arg("schema"));
    let schema: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(schema["title"], "Scene");
    for field in [
        "format",
        "blocks",
        "clutter",
        "dynamic",
        "light_regions",
        "settings",
    ] {
        assert!(
            !schema["properties"][field].is_null(),
            "schema lacks {field}"
        );
    }
}

/// `bake` and `eval --method drt --png` on the example scene with mesh clutter
/// (`scenes/cornell_mesh`, settings scaled down): RESULT.json holds the mesh's texels and the
/// atlas PNG is written.
#[test]
fn bake_and_eval_a_scene_with_mesh_clutter() {
    let dir = workdir("mesh");
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell_mesh");
    for f in ["short_box.gltf", "short_box.bin", "lights.json"] {
        std::fs::copy(src.join(f), dir.join(f)).unwrap();
    }
    let mut scene: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(src.join("scene.json")).unwrap()).unwrap();
    scene["settings"]["texels_per_face"] = 4.into();
    scene["settings"]["rays_per_texel"] = 64.into();
    std::fs::write(dir.join("scene.json"), scene.to_string()).unwrap();
    let bundle = dir.join("out.lfb");
    run(lightfarm()
        .arg("bake")
        .arg(dir.join("scene.json"))
        .arg("-o")
        .arg(&bundle)
        .arg("--no-cache"));
    let result = dir.join("drt.json");
    let png = dir.join("ind.png");
    run(lightfarm()
        .arg("eval")
        .arg(&bundle)
        .arg("--lights")
        .arg(dir.join("lights.json"))
        .args(["--method", "drt", "-o"])
        .arg(&result)
        .arg("--png")
        .arg(&png));
    let parsed: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&result).unwrap()).unwrap();
    let mesh_texels = parsed["texels"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|t| t["surface"] == "clutter:short_box")
        .count();
    assert!(mesh_texels > 0, "RESULT.json has no mesh texels");
    assert!(std::fs::read(&png).unwrap().starts_with(b"\x89PNG"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// `frame-time --update one-light` times both ways frame by frame, or, with `--update-alone`,
/// relighting by the change alone (no full line, no speedup); either way the update ends
/// where relighting everything ends, to float rounding at one bounce. `--update-alone`
/// without `--update one-light` is refused.
#[test]
fn frame_time_times_one_light_both_ways_or_the_update_alone() {
    let dir = workdir("one-light");
    let (scene, lights) = write_scene(&dir);
    let bundle = dir.join("out.lfb");
    run(lightfarm()
        .arg("bake")
        .arg(&scene)
        .arg("-o")
        .arg(&bundle)
        .arg("--no-cache"));
    for alone in [false, true] {
        let mut cmd = lightfarm();
        cmd.arg("frame-time")
            .arg(&bundle)
            .arg("--lights")
            .arg(&lights)
            .args(["--update", "one-light", "--bounces", "1", "--frames", "6"]);
        if alone {
            cmd.arg("--update-alone");
        }
        let out = run(&mut cmd);
        let has = |way: &str| out.lines().any(|l| l.contains(&format!(" way={way} ")));
        assert_eq!((has("full"), has("update")), (!alone, true), "{out}");
        let last = out.lines().last().unwrap();
        assert_eq!(last.contains(" speedup="), !alone, "{last}");
        let value = |key: &str| -> f64 {
            let at = last.find(key).unwrap_or_else(|| panic!("{key} in {last}"));
            last[at + key.len()..]
                .split(' ')
                .next()
                .unwrap()
                .parse()
                .unwrap()
        };
        assert!(value("median_ms=") > 0.0, "{last}");
        assert!(value("drift_rel_l2=") < 1e-4, "{last}");
    }
    // Without a light to move there is nothing to time alone: refused, by name.
    for update in [None, Some("one-object")] {
        let mut cmd = lightfarm();
        cmd.arg("frame-time")
            .arg(&bundle)
            .arg("--lights")
            .arg(&lights)
            .args(["--update-alone", "--frames", "2"]);
        if let Some(u) = update {
            cmd.args(["--update", u]);
        }
        let out = cmd.output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{update:?}: {err}");
        assert!(
            err.contains("--update-alone times `--update one-light`"),
            "{err}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The writing end of a pipe whose reader is already closed: every write to it fails with
/// `BrokenPipe`, from the first.
fn reader_gone() -> std::io::PipeWriter {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    writer
}

/// Runs `cmd` with its stdout's reader gone before anything is written (`lightfarm … | head`
/// with a reader that has already left): the command must finish as it would and exit 0, no
/// panic ("failed printing to stdout: Broken pipe" was what `println!` gave).
fn run_with_stdout_closed(cmd: &mut Command) {
    let out = cmd
        .stdout(reader_gone())
        .stderr(std::process::Stdio::piped())
        .output()
        .expect("run lightfarm");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{cmd:?}: {stderr}");
    assert!(!stderr.contains("panicked"), "{cmd:?}: {stderr}");
}

#[test]
fn reports_whose_reader_left_early_are_no_error() {
    let seed = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../client/fuzz/corpus/decode/tiny-u8.lfb"
    );
    let report = run(lightfarm().args(["inspect", seed]));
    assert!(report.contains("exact clutter gather"), "{report}");
    run_with_stdout_closed(lightfarm().args(["inspect", seed]));
    // A bake whose report has no reader still writes its bundle.
    let dir = workdir("closed-stdout");
    let (scene, _) = write_scene(&dir);
    let bundle = dir.join("out.lfb");
    run_with_stdout_closed(
        lightfarm()
            .arg("bake")
            .arg(&scene)
            .arg("-o")
            .arg(&bundle)
            .arg("--no-cache"),
    );
    assert!(bundle.exists());
    run(lightfarm().arg("inspect").arg(&bundle));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_service_serves_with_its_stdout_reader_gone() {
    use std::io::{BufRead, Read, Write};
    // Its "listening" line goes to a pipe without a reader (it used to panic there and exit).
    /// Kills the service when the test ends, passed or failed.
    struct Service(std::process::Child);
    impl Drop for Service {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
    let dir = workdir("serve-closed-stdout");
    let mut service = Service(
        lightfarm()
            .args(["serve", "--addr", "127.0.0.1:0", "--data"])
            .arg(dir.join("data"))
            .stdout(reader_gone())
            .stderr(std::process::Stdio::piped())
            .env("RUST_BACKTRACE", "0")
            .env("NO_COLOR", "1")
            .spawn()
            .expect("run lightfarm serve"),
    );
    // The address, from the log line on stderr (plain: `NO_COLOR`).
    let mut log = std::io::BufReader::new(service.0.stderr.take().unwrap());
    let mut addr = None;
    let mut line = String::new();
    while addr.is_none() && log.read_line(&mut line).unwrap() > 0 {
        addr = line
            .split_once("listening on http://")
            .map(|(_, a)| a.split_whitespace().next().unwrap().to_string());
        line.clear();
    }
    let addr = addr.expect("the service logs its address");
    let healthz = || {
        let mut stream = std::net::TcpStream::connect(&addr).expect("the service is up");
        stream
            .write_all(b"GET /healthz HTTP/1.1\r\nHost: lightfarm\r\nConnection: close\r\n\r\n")
            .unwrap();
        let mut answer = String::new();
        stream.read_to_string(&mut answer).unwrap();
        assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    };
    healthz();
    // The line is written just after the log line, and a panic there took the process down a
    // moment later (while other threads still answered): still up well after it.
    std::thread::sleep(std::time::Duration::from_millis(500));
    assert!(
        service.0.try_wait().unwrap().is_none(),
        "the service exited"
    );
    healthz();
    drop(service);
    let _ = std::fs::remove_dir_all(&dir);
}
