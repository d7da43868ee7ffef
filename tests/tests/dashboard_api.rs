//! End-to-end tests of what the dashboard stands on, against a real `lightfarm serve` process:
//! the bake and scene listings (newest first, paged, per team), the glTF preview of a finished
//! bake (byte-identical to `lightfarm export` of the same bundle, one and all bounces, lit ≠
//! indirect, texture sizes following the texel density, 0 errors from the Khronos validator
//! when `tests/browser` has its npm packages), and the dashboard page itself with every file it
//! loads.

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::Duration;

use lightfarm_client::ServiceClient;
use lightfarm_tests::{scene_dir, spawn_listening};
use serde_json::{json, Value};

/// A `lightfarm serve` process on 127.0.0.1:0.
struct Server {
    child: Child,
    addr: String,
}

impl Server {
    fn start(data: &Path, config: &str) -> Server {
        let config_path = data.with_extension("toml");
        std::fs::write(&config_path, config).unwrap();
        let (child, addr) = spawn_listening(
            Command::new(env!("CARGO_BIN_EXE_lightfarm-test-server"))
                .args(["--addr", "127.0.0.1:0", "--data"])
                .arg(data)
                .arg("--config")
                .arg(&config_path),
        );
        Server { child, addr }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

const TWO_TEAMS: &str = "[[teams]]\nname = \"red\"\ntoken = \"red-token\"\n\
                         [[teams]]\nname = \"blue\"\ntoken = \"blue-token\"\n";

fn data_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lightfarm-dash-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn scene_text(name: &str) -> String {
    std::fs::read_to_string(scene_dir(name).join("scene.json")).unwrap()
}

fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .build()
        .into()
}

/// GET as `token`: status and body.
fn get(server: &Server, token: &str, path: &str) -> (u16, Vec<u8>) {
    let mut r = agent()
        .get(format!("{}{path}", server.addr))
        .header("Authorization", format!("Bearer {token}"))
        .call()
        .unwrap();
    (r.status().as_u16(), r.body_mut().read_to_vec().unwrap())
}

fn get_json(server: &Server, token: &str, path: &str) -> (u16, Value) {
    let (status, body) = get(server, token, path);
    (status, serde_json::from_slice(&body).unwrap())
}

/// POST a preview request as `token`: status and body.
fn preview(server: &Server, token: &str, bake: &str, request: &Value) -> (u16, Vec<u8>) {
    let mut r = agent()
        .post(format!("{}/v1/bakes/{bake}/preview.glb", server.addr))
        .header("Authorization", format!("Bearer {token}"))
        .header("content-type", "application/json")
        .send(request.to_string())
        .unwrap();
    (r.status().as_u16(), r.body_mut().read_to_vec().unwrap())
}

fn ids(page: &Value) -> Vec<String> {
    page["bakes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b["id"].as_str().unwrap().to_string())
        .collect()
}

#[test]
fn listings_are_newest_first_paged_and_per_team() {
    let data = data_dir("listing");
    let server = Server::start(&data, TWO_TEAMS);
    let red = ServiceClient::new(&server.addr).with_token("red-token");
    let blue = ServiceClient::new(&server.addr).with_token("blue-token");
    let scene = red.create_scene(&scene_text("cornell")).unwrap().id;
    let mut submitted = Vec::new();
    for rays in [16, 17, 18] {
        let settings = json!({"texels_per_face": 4, "rays_per_texel": rays});
        submitted.push(red.submit_bake(&scene, settings).unwrap().id);
        std::thread::sleep(Duration::from_millis(20));
    }
    let blue_scene = blue.create_scene(&scene_text("corridor")).unwrap().id;
    let blue_bake = blue
        .submit_bake(
            &blue_scene,
            json!({"texels_per_face": 4, "rays_per_texel": 16}),
        )
        .unwrap()
        .id;

    // Two pages of two, newest first, then none.
    let (status, first) = get_json(&server, "red-token", "/v1/bakes?limit=2");
    assert_eq!(status, 200, "{first}");
    assert_eq!(
        ids(&first),
        vec![submitted[2].clone(), submitted[1].clone()]
    );
    let next = first["next"].as_str().unwrap();
    let (_, second) = get_json(&server, "red-token", next);
    assert_eq!(ids(&second), vec![submitted[0].clone()]);
    assert!(second["next"].is_null());
    // Blue sees only its own bake and scene.
    let (_, blue_page) = get_json(&server, "blue-token", "/v1/bakes");
    assert_eq!(ids(&blue_page), vec![blue_bake.clone()]);
    let (_, scenes) = get_json(&server, "blue-token", "/v1/scenes");
    let listed: Vec<&str> = scenes["scenes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["id"].as_str().unwrap())
        .collect();
    assert_eq!(listed, vec![blue_scene.as_str()]);
    assert_eq!(scenes["scenes"][0]["name"], "corridor");
    // The state filter: once all three finished, `succeeded` lists them and `queued` none.
    for id in &submitted {
        red.wait(id, Duration::from_secs(300)).unwrap();
    }
    let (_, done) = get_json(&server, "red-token", "/v1/bakes?state=succeeded");
    assert_eq!(ids(&done).len(), 3);
    let (_, queued) = get_json(&server, "red-token", "/v1/bakes?state=queued");
    assert!(ids(&queued).is_empty());
    // Bad parameters are 400s naming the parameter; no token is a 401.
    for (path, word) in [
        ("/v1/bakes?limit=0", "limit"),
        ("/v1/bakes?cursor=xyz", "cursor"),
        ("/v1/bakes?state=baking", "state"),
        ("/v1/scenes?limit=201", "limit"),
    ] {
        let (status, body) = get_json(&server, "red-token", path);
        assert_eq!(status, 400, "{path}: {body}");
        assert!(
            body["error"].as_str().unwrap().contains(word),
            "{path}: {body}"
        );
    }
    let (status, _) = get(&server, "nobody", "/v1/bakes");
    assert_eq!(status, 401);
    drop(server);
    let _ = std::fs::remove_dir_all(&data);
}

/// The GLB's JSON chunk.
fn glb_json(glb: &[u8]) -> Value {
    assert_eq!(&glb[..4], b"glTF");
    let length = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    serde_json::from_slice(&glb[20..20 + length]).unwrap()
}

/// Width and height of every PNG image in the GLB.
fn image_sizes(glb: &[u8]) -> Vec<(u32, u32)> {
    let doc = glb_json(glb);
    let json_length = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let bin = &glb[20 + json_length + 8..];
    doc["images"]
        .as_array()
        .unwrap()
        .iter()
        .map(|image| {
            let view = &doc["bufferViews"][image["bufferView"].as_u64().unwrap() as usize];
            let at = view["byteOffset"].as_u64().unwrap() as usize;
            let png = &bin[at..];
            assert_eq!(&png[1..4], b"PNG");
            let word = |k: usize| u32::from_be_bytes(png[k..k + 4].try_into().unwrap());
            (word(16), word(20))
        })
        .collect()
}

/// Runs the Khronos validator (tests/browser, `npm ci` there) on `glb`; `None` when node or the
/// package is missing.
fn validate(glb: &Path) -> Option<String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("browser");
    if !dir.join("node_modules/gltf-validator").exists() {
        eprintln!("gltf-validator not installed (cd tests/browser && npm ci): validation skipped");
        return None;
    }
    let out = match Command::new("node")
        .arg(dir.join("validate_gltf.mjs"))
        .arg(glb)
        .output()
    {
        Ok(out) => out,
        Err(e) => {
            eprintln!("node cannot run ({e}): validation skipped");
            return None;
        }
    };
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(out.status.success(), "validator: {text}");
    Some(text)
}

#[test]
fn preview_is_the_export_of_the_bundle_and_passes_the_validator() {
    let data = data_dir("preview");
    let server = Server::start(&data, TWO_TEAMS);
    let red = ServiceClient::new(&server.addr).with_token("red-token");
    let scene = red.create_scene(&scene_text("maze")).unwrap().id;
    let texels_per_face = 6;
    let settings = json!({"texels_per_face": texels_per_face, "rays_per_texel": 64});
    let bake = red.submit_bake(&scene, settings).unwrap().id;
    // A bake that has not finished has no preview.
    let lights: Value = serde_json::from_str(
        &std::fs::read_to_string(scene_dir("maze").join("lights.json")).unwrap(),
    )
    .unwrap();
    let done = red.wait(&bake, Duration::from_secs(600)).unwrap();
    let lit_request = json!({"lights": lights, "light": "lit", "bounces": "all"});
    let (status, lit) = preview(&server, "red-token", &bake, &lit_request);
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&lit));
    // Blue cannot preview red's bake; a bad light set is a 422 naming the light.
    let (status, _) = preview(&server, "blue-token", &bake, &lit_request);
    assert_eq!(status, 404);
    let bad = json!({"lights": {"lights": [{"kind": "point", "position": [0, 1, 0], "intensity": [-1, 0, 0]}]}});
    let (status, body) = preview(&server, "red-token", &bake, &bad);
    assert_eq!(status, 422);
    assert!(String::from_utf8_lossy(&body).contains("lights[0]"));

    // The maze: 19 blocks and 4 pillars, one mesh each, and its 4 lamps.
    let doc = glb_json(&lit);
    let maze: Value = serde_json::from_str(&scene_text("maze")).unwrap();
    let objects =
        maze["blocks"].as_array().unwrap().len() + maze["clutter"].as_array().unwrap().len();
    assert_eq!(doc["meshes"].as_array().unwrap().len(), objects);
    assert_eq!(
        doc["extensions"]["KHR_lights_punctual"]["lights"]
            .as_array()
            .unwrap()
            .len(),
        4
    );
    // Texture size follows the texel density: a block's texture holds each face's T×T texels
    // plus a border, so it is at least T + 2 wide, and grows with T.
    let sizes = image_sizes(&lit);
    assert_eq!(sizes.len(), objects);
    assert!(
        sizes
            .iter()
            .all(|&(w, h)| w >= texels_per_face + 2 && h >= texels_per_face + 2),
        "{sizes:?}"
    );

    // The same bundle through `lightfarm export` gives the same bytes.
    let bundle_path = data.join("maze.lfb");
    let fetched = red
        .fetcher(data.join("cache"))
        .fetch(&red.bundle_url(done.bundle.as_ref().unwrap()))
        .unwrap();
    std::fs::write(&bundle_path, &fetched.bytes).unwrap();
    let lights_path = scene_dir("maze").join("lights.json");
    let export_path = data.join("maze.glb");
    lightfarm_server::cli::export::run(lightfarm_server::cli::export::ExportArgs {
        bundle: bundle_path.clone(),
        lights: lights_path,
        out: export_path.clone(),
        options: lightfarm_server::export::ExportOptions::default(),
    })
    .unwrap();
    assert_eq!(std::fs::read(&export_path).unwrap(), lit);
    // One bounce is `export --bounces 1`, and not the all-bounce light.
    let one_request = json!({"lights": lights, "light": "indirect", "bounces": "one"});
    let (status, one) = preview(&server, "red-token", &bake, &one_request);
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&one));
    let one_path = data.join("maze-one.glb");
    lightfarm_server::cli::export::run(lightfarm_server::cli::export::ExportArgs {
        bundle: bundle_path.clone(),
        lights: scene_dir("maze").join("lights.json"),
        out: one_path.clone(),
        options: lightfarm_server::export::ExportOptions {
            mode: lightfarm_server::export::LightMode::Indirect,
            bounces: lightfarm_proto::bounces::BounceCount::ONE,
        },
    })
    .unwrap();
    assert_eq!(std::fs::read(&one_path).unwrap(), one);
    assert_eq!(glb_json(&one)["asset"]["extras"]["lightfarm"]["bounces"], 1);

    // Indirect-only is darker than lit (direct + indirect, texel by texel): its exposure is
    // larger (the auto exposure maps a lower 99th percentile to white). Maze, T = 6, all
    // bounces: 1.42 against 0.81 (one bounce: more than twice).
    let indirect_request = json!({"lights": lights, "light": "indirect"});
    let (status, indirect) = preview(&server, "red-token", &bake, &indirect_request);
    assert_eq!(status, 200);
    let exposure = |glb: &[u8]| {
        glb_json(glb)["asset"]["extras"]["lightfarm"]["exposure"]
            .as_f64()
            .unwrap()
    };
    assert!(
        exposure(&indirect) > 1.25 * exposure(&lit),
        "{} vs {}",
        exposure(&indirect),
        exposure(&lit)
    );
    assert_ne!(image_sizes(&indirect), Vec::new());
    // All bounces add light to the first: the auto exposure of the indirect light is lower.
    assert!(
        exposure(&indirect) < exposure(&one),
        "all bounces {} vs one {}",
        exposure(&indirect),
        exposure(&one)
    );
    assert_eq!(
        glb_json(&indirect)["asset"]["extras"]["lightfarm"]["bounces"],
        "all"
    );

    if let Some(report) = validate(&export_path) {
        eprintln!("{report}");
        assert!(report.contains("errors=0"), "{report}");
    }
    drop(server);
    let _ = std::fs::remove_dir_all(&data);
}

/// The floats of accessor `index` in the GLB (tightly packed, as the export writes them).
fn accessor_floats(glb: &[u8], index: u64) -> Vec<f32> {
    let doc = glb_json(glb);
    let json_length = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let bin = &glb[20 + json_length + 8..];
    let accessor = &doc["accessors"][index as usize];
    let view = &doc["bufferViews"][accessor["bufferView"].as_u64().unwrap() as usize];
    let at = view["byteOffset"].as_u64().unwrap_or(0) as usize;
    let len = view["byteLength"].as_u64().unwrap() as usize;
    bin[at..at + len]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect()
}

#[test]
fn the_export_draws_posed_dynamic_objects_lit_by_the_frame() {
    let (mut scene, lights) = lightfarm_tests::load_scene("ball_corridor", 4, 32);
    scene.settings.dnrt.resolution = 4;
    scene.settings.dnrt.rays = 16;
    let dir = scene_dir("ball_corridor");
    let (bytes, _) = lightfarm_tests::bake_scene(
        &scene,
        &dir,
        lightfarm_proto::scene::Transport::Lightfield,
        false,
    );
    let export = |set: &lightfarm_proto::lights::LightSet| {
        let bundle = lightfarm_client::decode(&bytes).unwrap();
        lightfarm_server::export::export_glb(bundle, set, Default::default())
            .unwrap()
            .0
    };
    let glb = export(&lights);
    let doc = glb_json(&glb);
    let ball = doc["meshes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|m| m["name"] == "dynamic:red_ball")
        .expect("the posed ball is drawn");
    let attributes = &ball["primitives"][0]["attributes"];
    // All 320 triangles of ball.obj, at the pose: its bounds are the pose's translation ± the
    // radius (0.35 m; the rotation is about y, which the icosphere's bounds barely notice).
    let position = &doc["accessors"][attributes["POSITION"].as_u64().unwrap() as usize];
    assert_eq!(position["count"], 960);
    let t = lights.poses[0].translation;
    for k in 0..3 {
        let (lo, hi) = (
            position["min"][k].as_f64().unwrap(),
            position["max"][k].as_f64().unwrap(),
        );
        assert!(
            lo >= t[k] - 0.351 && hi <= t[k] + 0.351,
            "axis {k}: {lo}..{hi}"
        );
        assert!(hi - lo > 0.6, "axis {k}: {lo}..{hi}");
    }
    // Coloured by its albedo (0.8, 0.1, 0.08) under white light: red, and lit on the side
    // facing the lamp more than underneath, where only the floor's light reaches it (measured
    // 0.23 to 0.56 in linear red after the tone curve).
    let colours = accessor_floats(&glb, attributes["COLOR_0"].as_u64().unwrap());
    let mean = |c: usize| colours.iter().skip(c).step_by(4).sum::<f32>() / 960.0;
    assert!(
        mean(0) > 3.0 * mean(1) && mean(0) > 0.05,
        "{} {}",
        mean(0),
        mean(1)
    );
    let red: Vec<f32> = colours.iter().step_by(4).copied().collect();
    let (dim, bright) = red
        .iter()
        .fold((f32::MAX, 0.0f32), |(lo, hi), &x| (lo.min(x), hi.max(x)));
    assert!(bright > 2.0 * dim, "{dim}..{bright}");
    // Without a pose nothing is drawn.
    let unposed = lightfarm_proto::lights::LightSet {
        poses: vec![],
        ..lights.clone()
    };
    let doc = glb_json(&export(&unposed));
    assert!(doc["meshes"]
        .as_array()
        .unwrap()
        .iter()
        .all(|m| !m["name"].as_str().unwrap().starts_with("dynamic:")));
    let data = data_dir("export-dynamic");
    std::fs::create_dir_all(&data).unwrap();
    let path = data.join("ball.glb");
    std::fs::write(&path, &glb).unwrap();
    if let Some(report) = validate(&path) {
        eprintln!("{report}");
        assert!(report.contains("errors=0"), "{report}");
    }
    let _ = std::fs::remove_dir_all(&data);
}

#[test]
fn dashboard_page_and_its_files_are_served() {
    let data = data_dir("page");
    let server = Server::start(&data, TWO_TEAMS);
    // The page needs no token (it asks for one); the API behind it does.
    let (status, page) = get(&server, "", "/");
    assert_eq!(status, 200);
    let page = String::from_utf8(page).unwrap();
    assert!(page.contains("<title>lightfarm</title>"));
    for path in [
        "/ui/app.js",
        "/ui/api.js",
        "/ui/preview.js",
        "/ui/style.css",
        "/ui/vendor/three/three.module.min.js",
        "/ui/vendor/three/addons/loaders/GLTFLoader.js",
    ] {
        let (status, body) = get(&server, "", path);
        assert_eq!(status, 200, "{path}");
        assert!(body.len() > 100, "{path}");
    }
    assert_eq!(get(&server, "", "/ui/missing.js").0, 404);
    drop(server);
    let _ = std::fs::remove_dir_all(&data);
}
