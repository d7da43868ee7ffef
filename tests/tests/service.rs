//! End-to-end tests of `lightfarm serve`: the real server as a process on 127.0.0.1:0, driven
//! through the client crate's `ServiceClient` and `BundleFetcher` (and raw HTTP where a test
//! needs headers): upload, bake, SSE progress, cancel, ETag/304 and ranges, auth isolation,
//! 429 under a burst, restart after SIGKILL, a corrupt stored bundle.

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use lightfarm_client::{decode, ServiceClient};
use lightfarm_proto::api::{BakeEvent, JobState};
use lightfarm_proto::scene::Scene;
use lightfarm_server::bake::pipeline::encoding::encode_options;
use lightfarm_server::bake::progress::NoProgress;
use lightfarm_server::bake::{bake, BakeOptions};
use lightfarm_tests::{scene_dir, spawn_listening};
use serde_json::json;

/// A `lightfarm serve` process.
struct Server {
    child: Child,
    addr: String,
    data: PathBuf,
    config: Option<PathBuf>,
}

impl Server {
    fn start(data: &Path, config: Option<&str>) -> Server {
        let config = config.map(|text| {
            let path = data.with_extension("toml");
            std::fs::write(&path, text).unwrap();
            path
        });
        Server::spawn(data.to_path_buf(), config)
    }

    fn spawn(data: PathBuf, config: Option<PathBuf>) -> Server {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_lightfarm-test-server"));
        cmd.args(["--addr", "127.0.0.1:0", "--data"]).arg(&data);
        if let Some(c) = &config {
            cmd.arg("--config").arg(c);
        }
        let (child, addr) = spawn_listening(&mut cmd);
        Server {
            child,
            addr,
            data,
            config,
        }
    }

    fn client(&self) -> ServiceClient {
        ServiceClient::new(&self.addr)
    }

    fn kill9(&mut self) {
        self.child.kill().unwrap(); // SIGKILL on unix
        self.child.wait().unwrap();
    }

    fn restart(mut self) -> Server {
        self.kill9();
        Server::spawn(self.data.clone(), self.config.clone())
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn data_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lightfarm-service-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn scene_text(name: &str) -> String {
    std::fs::read_to_string(scene_dir(name).join("scene.json")).unwrap()
}

/// An OBJ cube of half-size `h` about `c`, outward-wound.
fn cube_obj(c: [f64; 3], h: f64) -> String {
    lightfarm_proto::testing::box_obj(c.map(|x| x - h), c.map(|x| x + h))
}

fn fast_settings() -> serde_json::Value {
    json!({"texels_per_face": 6, "rays_per_texel": 64})
}

/// The bundle `lightfarm bake` writes for `scene` (JSON, meshes in `dir`): baked in this
/// process and encoded with the scene's codec settings.
fn cli_bytes(scene: &serde_json::Value, dir: &Path) -> Vec<u8> {
    let scene = Scene::from_json(&scene.to_string()).unwrap();
    let (bundle, _) = bake(&scene, dir, &BakeOptions::default(), &NoProgress).unwrap();
    bundle.encode_with(&encode_options(&scene.settings, None)).0
}

/// Waits for a final state.
fn wait(client: &ServiceClient, id: &str) -> lightfarm_proto::api::BakeStatus {
    client.wait(id, Duration::from_secs(300)).unwrap()
}

#[test]
fn upload_bake_watch_and_fetch() {
    let data = data_dir("main");
    let server = Server::start(&data, None);
    let client = server.client();

    // An OBJ prop as mesh clutter of the cornell box.
    let obj = cube_obj([2.75, 4.5, 2.75], 0.3);
    let asset = client.upload_asset(obj.as_bytes()).unwrap();
    assert_eq!(asset.format, "obj");
    assert_eq!(asset.triangles, 12);
    let mut scene: serde_json::Value = serde_json::from_str(&scene_text("cornell")).unwrap();
    scene["clutter"]
        .as_array_mut()
        .unwrap()
        .push(json!({"id": "lamp_shade", "mesh": asset.hash, "albedo": [0.5, 0.5, 0.5]}));
    let created = client.create_scene(&scene.to_string()).unwrap();
    assert_eq!(created.clutter, 3);

    let submitted = client.submit_bake(&created.id, fast_settings()).unwrap();
    assert!(!submitted.cached);
    let events: Vec<BakeEvent> = client.events(&submitted.id).unwrap().collect();
    let stages: Vec<&str> = events
        .iter()
        .filter_map(|e| match e {
            BakeEvent::Stage { stage, .. } => Some(stage.as_str()),
            _ => None,
        })
        .collect();
    assert!(stages.contains(&"clutter operators"), "{stages:?}");
    let overall: Vec<f64> = events
        .iter()
        .filter_map(|e| match e {
            BakeEvent::Progress { overall, .. } => Some(*overall),
            _ => None,
        })
        .collect();
    assert!(!overall.is_empty());
    assert!(overall.windows(2).all(|w| w[1] >= w[0]), "{overall:?}");
    assert!(overall.iter().all(|f| (0.0..=1.0).contains(f)));
    let Some(BakeEvent::State {
        state: JobState::Succeeded,
        bundle: Some(hash),
        ..
    }) = events.last()
    else {
        panic!("stream did not end with success: {:?}", events.last());
    };
    let status = client.bake_status(&submitted.id).unwrap();
    assert_eq!(status.state, JobState::Succeeded);
    assert_eq!(status.bundle.as_ref(), Some(hash));
    assert!(status.stages.iter().any(|s| s.stage == "clutter operators"));
    assert_eq!(status.progress, 1.0);

    // The same bake again: answered at once from the finished job.
    let again = client.submit_bake(&created.id, fast_settings()).unwrap();
    assert!(again.cached);
    assert_eq!(again.bundle.as_ref(), Some(hash));

    // Fetch through the client: decodes, and is byte-identical to an in-process bake.
    let cache = data.join("client-cache");
    let fetcher = client.fetcher(&cache);
    let fetched = fetcher.fetch(&client.bundle_url(hash)).unwrap();
    assert!(!fetched.from_cache);
    let bundle = decode(&fetched.bytes).unwrap();
    assert!(bundle.drt.is_some());
    let local_dir = data.join("local");
    std::fs::create_dir_all(&local_dir).unwrap();
    std::fs::write(local_dir.join(format!("{}.obj", asset.hash)), &obj).unwrap();
    scene["clutter"][2]["mesh"] = json!(format!("{}.obj", asset.hash));
    scene["settings"]["texels_per_face"] = json!(6);
    scene["settings"]["rays_per_texel"] = json!(64);
    let local_bytes = cli_bytes(&scene, &local_dir);
    assert!(
        local_bytes == fetched.bytes,
        "service bundle differs from the CLI bake"
    );

    // Revalidation: 304, served from the client's cache.
    let second = fetcher.fetch(&client.bundle_url(hash)).unwrap();
    assert!(second.from_cache);
    assert_eq!(second.bytes, fetched.bytes);

    // A byte range.
    let agent: ureq::Agent = ureq::Agent::config_builder()
        .http_status_as_error(false)
        .build()
        .into();
    let mut r = agent
        .get(client.bundle_url(hash))
        .header("Range", "bytes=100-199")
        .call()
        .unwrap();
    assert_eq!(r.status().as_u16(), 206);
    assert_eq!(
        r.headers().get("content-range").unwrap().to_str().unwrap(),
        format!("bytes 100-199/{}", fetched.bytes.len())
    );
    let part = r.body_mut().read_to_vec().unwrap();
    assert_eq!(part, fetched.bytes[100..200]);
    let r = agent
        .get(client.bundle_url(hash))
        .header("Range", format!("bytes={}-", fetched.bytes.len()))
        .call()
        .unwrap();
    assert_eq!(r.status().as_u16(), 416);

    // The shapes listing counts the use; metrics and the OpenAPI document answer.
    let shapes: serde_json::Value = agent
        .get(format!("{}/v1/shapes", server.addr))
        .call()
        .unwrap()
        .body_mut()
        .read_to_string()
        .map(|t| serde_json::from_str(&t).unwrap())
        .unwrap();
    assert!(shapes.as_array().unwrap().iter().any(|s| s["uses"] == 1));
    let metrics = agent
        .get(format!("{}/metrics", server.addr))
        .call()
        .unwrap()
        .body_mut()
        .read_to_string()
        .unwrap();
    assert!(
        metrics.contains("lightfarm_bakes{state=\"succeeded\"} 1"),
        "{metrics}"
    );
    assert!(metrics.contains("lightfarm_cache_hits_total{cache=\"bake\"} 1"));
    let doc: serde_json::Value = agent
        .get(format!("{}/openapi.json", server.addr))
        .call()
        .unwrap()
        .body_mut()
        .read_to_string()
        .map(|t| serde_json::from_str(&t).unwrap())
        .unwrap();
    assert!(doc["paths"]["/v1/bakes"].is_object());

    // The service kept the level's encodings in its operator cache. A bake of the scene with a
    // box moved reads them (the unchanged shapes and transport are neither encoded nor
    // compressed again) and still stores the CLI's bytes.
    let memo_entries = std::fs::read_dir(data.join("operators").join("encodings"))
        .map(|d| d.count())
        .unwrap_or(0);
    assert!(memo_entries >= 2, "{memo_entries} encoding memo entries");
    let mut moved = scene.clone();
    moved["clutter"][0]["box"]["min"][0] = json!(3.3);
    moved["clutter"][0]["box"]["max"][0] = json!(4.95);
    let mut moved_service = moved.clone();
    moved_service["clutter"][2]["mesh"] = json!(asset.hash);
    let created = client.create_scene(&moved_service.to_string()).unwrap();
    let submitted = client.submit_bake(&created.id, fast_settings()).unwrap();
    let status = wait(&client, &submitted.id);
    assert_eq!(status.state, JobState::Succeeded, "{status:?}");
    let moved_fetched = fetcher
        .fetch(&client.bundle_url(status.bundle.as_ref().unwrap()))
        .unwrap();
    let moved_bytes = cli_bytes(&moved, &local_dir);
    assert!(
        moved_bytes == moved_fetched.bytes && moved_bytes != local_bytes,
        "the rebake through the memo differs from the CLI bake"
    );
    drop(server);
    let _ = std::fs::remove_dir_all(&data);
}

#[test]
fn validation_and_limits_give_clear_errors() {
    let data = data_dir("limits");
    let server = Server::start(
        &data,
        Some(
            "[limits]\nmax_body_bytes = 20000\nmax_triangles = 10\nmax_rays_per_bake = 1000000\n\
             [[teams]]\nname = \"solo\"\ntoken = \"solo-token\"\n",
        ),
    );
    let client = server.client().with_token("solo-token");
    // The same message as the CLI's.
    let bad = scene_text("cornell").replace("\"texels_per_face\": 16", "\"texels_per_face\": 0");
    let cli_message = Scene::from_json(&bad).unwrap_err().to_string();
    let e = client.create_scene(&bad).unwrap_err();
    assert_eq!(e.status(), Some(422));
    assert!(e.to_string().contains(&cli_message), "{e} vs {cli_message}");
    // Too many triangles, too large a body.
    let e = client
        .upload_asset(cube_obj([0.0; 3], 1.0).as_bytes())
        .unwrap_err();
    assert_eq!(e.status(), Some(413));
    assert!(e.to_string().contains("limits.max_triangles"), "{e}");
    let e = client.upload_asset(&vec![b'#'; 30000]).unwrap_err();
    assert_eq!(e.status(), Some(413));
    assert!(e.to_string().contains("limits.max_body_bytes"), "{e}");
    // A glTF that refers to a file on the server is refused: an asset must be self-contained.
    for uri in ["file:///etc/hostname", "../../Cargo.toml"] {
        let gltf = format!(
            r#"{{"asset":{{"version":"2.0"}},"buffers":[{{"uri":"{uri}","byteLength":4}}]}}"#
        );
        let e = client.upload_asset(gltf.as_bytes()).unwrap_err();
        assert_eq!(e.status(), Some(422), "{uri}: {e}");
        assert!(
            e.to_string()
                .contains(&format!("buffer 0 refers to the file \"{uri}\"")),
            "{uri}: {e}"
        );
    }
    // A mesh path that is no asset.
    let mut scene: serde_json::Value = serde_json::from_str(&scene_text("cornell")).unwrap();
    scene["clutter"][0] = json!({"id": "ghost", "mesh": "chair.obj", "albedo": [0.5, 0.5, 0.5]});
    let e = client.create_scene(&scene.to_string()).unwrap_err();
    assert_eq!(e.status(), Some(422));
    assert!(e.to_string().contains("clutter \"ghost\""), "{e}");
    // Over the ray budget with the scene's own settings; a bad override.
    let id = client.create_scene(&scene_text("cornell")).unwrap().id;
    let e = client.submit_bake(&id, json!({})).unwrap_err();
    assert_eq!(e.status(), Some(422));
    assert!(e.to_string().contains("limits.max_rays_per_bake"), "{e}");
    let e = client
        .submit_bake(&id, json!({"rays_per_texl": 4}))
        .unwrap_err();
    assert!(e.to_string().contains("settings.rays_per_texl"), "{e}");
    // No token, a wrong token.
    let e = server
        .client()
        .create_scene(&scene_text("cornell"))
        .unwrap_err();
    assert_eq!(e.status(), Some(401));
    let e = server
        .client()
        .with_token("solo-tokem")
        .bake_status(&id)
        .unwrap_err();
    assert_eq!(e.status(), Some(401));
    drop(server);
    let _ = std::fs::remove_dir_all(&data);
}

const TWO_TEAMS: &str = "[[teams]]\nname = \"red\"\ntoken = \"red-token\"\n\
                         [[teams]]\nname = \"blue\"\ntoken = \"blue-token\"\n";

#[test]
fn teams_see_only_their_own_objects() {
    let data = data_dir("teams");
    let server = Server::start(&data, Some(TWO_TEAMS));
    let red = server.client().with_token("red-token");
    let blue = server.client().with_token("blue-token");
    let scene = red.create_scene(&scene_text("cornell")).unwrap().id;
    let job = red.submit_bake(&scene, fast_settings()).unwrap().id;
    let done = wait(&red, &job);
    let hash = done.bundle.unwrap();
    // Blue cannot see red's bake, bundle, scene or events: 404, not 403.
    for e in [
        blue.bake_status(&job).unwrap_err(),
        blue.cancel_bake(&job).unwrap_err(),
        blue.submit_bake(&scene, fast_settings()).unwrap_err(),
    ] {
        assert_eq!(e.status(), Some(404), "{e}");
    }
    assert!(blue.events(&job).is_err());
    let e = blue
        .fetcher(data.join("blue-cache"))
        .fetch(&blue.bundle_url(&hash))
        .unwrap_err();
    assert!(e.to_string().contains("404"), "{e}");
    // Red can; once blue uploads the same scene itself, its bake is the same job, cached.
    assert!(red
        .fetcher(data.join("red-cache"))
        .fetch(&red.bundle_url(&hash))
        .is_ok());
    let blue_scene = blue.create_scene(&scene_text("cornell")).unwrap().id;
    assert_eq!(blue_scene, scene);
    let blue_job = blue.submit_bake(&blue_scene, fast_settings()).unwrap();
    assert!(blue_job.cached);
    assert!(blue
        .fetcher(data.join("blue-cache"))
        .fetch(&blue.bundle_url(&hash))
        .is_ok());
    drop(server);
    let _ = std::fs::remove_dir_all(&data);
}

#[test]
fn burst_of_submissions_is_bounded_with_429() {
    let data = data_dir("burst");
    let server = Server::start(
        &data,
        Some(&format!(
            "[limits]\nqueue_capacity = 3\nconcurrent_bakes = 1\n{TWO_TEAMS}"
        )),
    );
    let red = server.client().with_token("red-token");
    let scene = red.create_scene(&scene_text("maze")).unwrap().id;
    let (mut accepted, mut refused) = (Vec::new(), 0);
    for seed in 0..12 {
        match red.submit_bake(
            &scene,
            json!({"seed": seed, "texels_per_face": 4, "rays_per_texel": 16}),
        ) {
            Ok(s) => accepted.push(s.id),
            Err(lightfarm_client::ServiceError::Api {
                status: 429,
                retry_after,
                message,
                ..
            }) => {
                assert!(retry_after.is_some_and(|s| s >= 1), "{retry_after:?}");
                assert!(message.contains("queue is full"), "{message}");
                refused += 1;
            }
            Err(e) => panic!("{e}"),
        }
    }
    // One may already be running, so 3 or 4 were taken.
    assert!((3..=4).contains(&accepted.len()), "{accepted:?}");
    assert_eq!(refused, 12 - accepted.len());
    for id in &accepted {
        red.cancel_bake(id).unwrap();
    }
    for id in &accepted {
        assert_eq!(wait(&red, id).state, JobState::Cancelled);
    }
    drop(server);
    let _ = std::fs::remove_dir_all(&data);
}

#[test]
fn cancel_stops_a_running_bake() {
    let data = data_dir("cancel");
    let server = Server::start(&data, None);
    let client = server.client();
    let scene = client.create_scene(&scene_text("maze")).unwrap().id;
    // Big enough to run for minutes.
    let job = client
        .submit_bake(
            &scene,
            json!({"texels_per_face": 16, "rays_per_texel": 4096}),
        )
        .unwrap()
        .id;
    let mut events = client.events(&job).unwrap();
    // Wait until texels are being processed.
    for event in events.by_ref() {
        if let BakeEvent::Progress { done, .. } = event {
            if done > 0 {
                break;
            }
        }
    }
    let asked = Instant::now();
    let status = client.cancel_bake(&job).unwrap();
    assert!(matches!(
        status.state,
        JobState::Running | JobState::Cancelled
    ));
    let final_event = events.last();
    let stopped_after = asked.elapsed();
    assert!(
        matches!(
            final_event,
            Some(BakeEvent::State {
                state: JobState::Cancelled,
                ..
            })
        ),
        "{final_event:?}"
    );
    eprintln!(
        "cancel: the bake stopped {:.3} s after DELETE",
        stopped_after.as_secs_f64()
    );
    // Generous for a loaded CI machine; the closing note gives the measured figure.
    assert!(stopped_after < Duration::from_secs(5), "{stopped_after:?}");
    assert_eq!(client.bake_status(&job).unwrap().state, JobState::Cancelled);
    // The pool is free again: a small bake runs to the end.
    let next = client
        .submit_bake(&scene, json!({"texels_per_face": 4, "rays_per_texel": 16}))
        .unwrap();
    assert_eq!(wait(&client, &next.id).state, JobState::Succeeded);
    drop(server);
    let _ = std::fs::remove_dir_all(&data);
}

#[test]
fn restart_after_sigkill_keeps_finished_and_requeues_running() {
    let data = data_dir("restart");
    let server = Server::start(&data, None);
    let client = server.client();
    let scene = client.create_scene(&scene_text("maze")).unwrap().id;
    let finished = client
        .submit_bake(&scene, json!({"texels_per_face": 4, "rays_per_texel": 16}))
        .unwrap();
    let finished = wait(&client, &finished.id);
    let hash = finished.bundle.clone().unwrap();
    let slow = client
        .submit_bake(&scene, json!({"texels_per_face": 8, "rays_per_texel": 256}))
        .unwrap()
        .id;
    let mut events = client.events(&slow).unwrap();
    assert!(events.any(|e| matches!(e, BakeEvent::Stage { .. })));

    let server = server.restart();
    let client = server.client();
    // The finished job and its bundle survive.
    let again = client.bake_status(&finished.id).unwrap();
    assert_eq!(again.state, JobState::Succeeded);
    let bytes = client
        .fetcher(data.join("cache"))
        .fetch(&client.bundle_url(&hash))
        .unwrap()
        .bytes;
    decode(&bytes).unwrap();
    // The running one was queued again and finishes.
    let requeued = client.bake_status(&slow).unwrap();
    assert!(matches!(
        requeued.state,
        JobState::Queued | JobState::Running | JobState::Succeeded
    ));
    let done = wait(&client, &slow);
    assert_eq!(done.state, JobState::Succeeded, "{:?}", done.error);
    drop(server);
    let _ = std::fs::remove_dir_all(&data);
}

#[test]
fn corrupt_stored_bundle_is_dropped_and_rebaked() {
    let data = data_dir("corrupt");
    let server = Server::start(&data, None);
    let client = server.client();
    let scene = client.create_scene(&scene_text("cornell")).unwrap().id;
    let job = client.submit_bake(&scene, fast_settings()).unwrap();
    let hash = wait(&client, &job.id).bundle.unwrap();
    let path = data.join("blobs/bundle").join(&hash);
    let mut bytes = std::fs::read(&path).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x40;
    std::fs::write(&path, &bytes).unwrap();
    // Never served corrupt.
    let e = client
        .fetcher(data.join("cache"))
        .fetch(&client.bundle_url(&hash))
        .unwrap_err();
    assert!(e.to_string().contains("404"), "{e}");
    // Baking again is not a cache hit; it rebuilds the identical bundle.
    let rebake = client.submit_bake(&scene, fast_settings()).unwrap();
    assert!(!rebake.cached);
    assert_eq!(wait(&client, &rebake.id).bundle.as_ref(), Some(&hash));
    let fetched = client
        .fetcher(data.join("cache"))
        .fetch(&client.bundle_url(&hash))
        .unwrap();
    decode(&fetched.bytes).unwrap();
    drop(server);
    let _ = std::fs::remove_dir_all(&data);
}

/// `POST /v1/bakes/{id}/evaluate` answers exactly what `lightfarm eval` writes for the bake's
/// bundle and the same lights (both methods; all bounces by default, or a fixed count), says
/// in its headers how many bounces it summed, and names what is wrong otherwise.
#[test]
fn evaluate_endpoint_equals_cli_eval() {
    use lightfarm_server::cli::eval::{run, EvalArgs};
    use lightfarm_server::cli::lightmap_files::LightmapFiles;

    let data = data_dir("evaluate");
    let server = Server::start(&data, None);
    let client = server.client();
    let scene = client.create_scene(&scene_text("cornell")).unwrap().id;
    let job = client.submit_bake(&scene, fast_settings()).unwrap();
    let hash = wait(&client, &job.id).bundle.unwrap();
    let fetched = client
        .fetcher(data.join("cache"))
        .fetch(&client.bundle_url(&hash))
        .unwrap();
    let bundle_path = data.join("cornell.lfb");
    std::fs::write(&bundle_path, &fetched.bytes).unwrap();
    // A light that is not the scene's own, so nothing could be precomputed for it.
    let lights = json!({"lights": [
        {"kind": "point", "position": [1.5, 4.0, 3.5], "intensity": [7.0, 5.0, 3.0]}
    ]})
    .to_string();
    let lights_path = data.join("lights.json");
    std::fs::write(&lights_path, &lights).unwrap();
    let agent: ureq::Agent = ureq::Agent::config_builder()
        .http_status_as_error(false)
        .build()
        .into();
    let url = format!("{}/v1/bakes/{}/evaluate", client.base(), job.id);
    // Cornell at T=6 has no probe volume, so MRT leaves the two clutter boxes out.
    use lightfarm_client::{Bounces, Method};
    let all = Bounces::default();
    let cases = [
        ("", Method::Drt, all, 3 * 6 * 36),
        ("?method=mrt", Method::Mrt, all, 6 * 36),
        ("?bounces=1", Method::Drt, Bounces::One, 3 * 6 * 36),
        ("?bounces=one&method=mrt", Method::Mrt, Bounces::One, 6 * 36),
        (
            "?method=mrt&bounces=3",
            Method::Mrt,
            Bounces::Fixed(3),
            6 * 36,
        ),
        ("?bounces=all", Method::Drt, all, 3 * 6 * 36),
    ];
    for (query, method, bounces, n_texels) in cases {
        let out = data.join(format!("result{}.json", query.len()));
        run(EvalArgs {
            bundle: bundle_path.clone(),
            lights: lights_path.clone(),
            method,
            bounces,
            out: out.clone(),
            lightmaps: LightmapFiles::default(),
            sh_out: None,
        })
        .unwrap();
        let cli: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
        let mut r = agent
            .post(format!("{url}{query}"))
            .header("content-type", "application/json")
            .send(lights.as_bytes())
            .unwrap();
        assert_eq!(r.status().as_u16(), 200, "{query}");
        let summed: u32 = r.headers()["lightfarm-bounces"]
            .to_str()
            .unwrap()
            .parse()
            .unwrap();
        match bounces {
            Bounces::One => assert_eq!(summed, 1, "{query}"),
            Bounces::Fixed(n) => assert_eq!(summed, n, "{query}"),
            _ => assert!(summed > 1, "{query}: all bounces summed {summed}"),
        }
        let remaining: f32 = r.headers()["lightfarm-remaining-fraction"]
            .to_str()
            .unwrap()
            .parse()
            .unwrap();
        assert!((0.0..1.0).contains(&remaining), "{query}: {remaining}");
        let served: serde_json::Value =
            serde_json::from_slice(&r.body_mut().read_to_vec().unwrap()).unwrap();
        // One closed block of 6 faces, and two clutter boxes of 6 faces each.
        assert_eq!(cli["texels"].as_array().unwrap().len(), n_texels, "{query}");
        assert_eq!(served, cli, "{query}: the service and the CLI disagree");
    }
    // Asked for it, the same document comes compressed.
    let mut r = agent
        .post(&url)
        .header("content-type", "application/json")
        .header("accept-encoding", "zstd")
        .send(lights.as_bytes())
        .unwrap();
    assert_eq!(r.status().as_u16(), 200);
    assert_eq!(r.headers()["content-encoding"], "zstd");
    let packed = r.body_mut().read_to_vec().unwrap();
    let unpacked = zstd::decode_all(packed.as_slice()).unwrap();
    assert!(
        packed.len() * 2 < unpacked.len(),
        "{} of {}",
        packed.len(),
        unpacked.len()
    );
    let served: serde_json::Value = serde_json::from_slice(&unpacked).unwrap();
    let cli: serde_json::Value =
        serde_json::from_slice(&std::fs::read(data.join("result0.json")).unwrap()).unwrap();
    assert_eq!(served, cli, "the compressed document is the CLI's");
    // Bad lights name the field; an unknown bake and a bad method are refused.
    let bad = json!({"lights": [
        {"kind": "point", "position": [1.0, 1.0, 1.0], "intensity": [1.0, -2.0, 1.0]}
    ]});
    let mut r = agent.post(&url).send(bad.to_string().as_bytes()).unwrap();
    assert_eq!(r.status().as_u16(), 422);
    let text = r.body_mut().read_to_string().unwrap();
    assert!(text.contains("lights[0]: intensity"), "{text}");
    let posed = json!({"lights": [], "poses": [{"id": "ghost", "translation": [1.0, 1.0, 1.0]}]});
    let mut r = agent.post(&url).send(posed.to_string().as_bytes()).unwrap();
    assert_eq!(r.status().as_u16(), 422);
    let text = r.body_mut().read_to_string().unwrap();
    assert!(text.contains("poses[0].id"), "{text}");
    let mut r = agent
        .post(format!("{url}?method=full"))
        .send(lights.as_bytes())
        .unwrap();
    let text = r.body_mut().read_to_string().unwrap();
    assert!(text.contains("method"), "{text}");
    let mut r = agent
        .post(format!("{url}?bounces=0"))
        .send(lights.as_bytes())
        .unwrap();
    assert_eq!(r.status().as_u16(), 422);
    let text = r.body_mut().read_to_string().unwrap();
    assert!(text.contains("bounces"), "{text}");
    let unknown = format!("{}/v1/bakes/{}/evaluate", client.base(), "0".repeat(64));
    let r = agent.post(&unknown).send(lights.as_bytes()).unwrap();
    assert_eq!(r.status().as_u16(), 404);
    drop(server);
    let _ = std::fs::remove_dir_all(&data);
}

#[test]
fn bundle_streams_mrt_sections_before_drt() {
    let data = data_dir("stream");
    let server = Server::start(&data, None);
    let client = server.client();
    let scene = client.create_scene(&scene_text("maze")).unwrap().id;
    let job = client
        .submit_bake(&scene, json!({"texels_per_face": 6, "rays_per_texel": 128}))
        .unwrap()
        .id;
    // The first announcement of final sections: the MRT part, before the clutter operators.
    let (sections, prefix_len) = client
        .events(&job)
        .unwrap()
        .find_map(|e| match e {
            BakeEvent::Sections { sections, bytes } => Some((sections, bytes)),
            _ => None,
        })
        .expect("a sections event");
    assert!(sections.contains(&"transport".to_string()), "{sections:?}");
    assert!(!sections.contains(&"drt".to_string()), "{sections:?}");
    let agent: ureq::Agent = ureq::Agent::config_builder()
        .http_status_as_error(false)
        .build()
        .into();
    let response = agent
        .get(format!("{}/v1/bakes/{job}/bundle", server.addr))
        .call()
        .unwrap();
    assert_eq!(response.status().as_u16(), 200);
    let mut reader = response.into_body().into_reader();
    let mut prefix = vec![0u8; prefix_len as usize];
    std::io::Read::read_exact(&mut reader, &mut prefix).unwrap();
    let partial = lightfarm_proto::bundle::Bundle::decode_prefix(&prefix).unwrap();
    assert!(!partial.complete);
    assert!(partial.bundle.transport.is_some());
    assert!(partial.bundle.drt.is_none());
    // The MRT part alone already makes a client runtime.
    let runtime = lightfarm_client::Runtime::new(partial.bundle);
    drop(runtime);
    // The rest arrives when the bake ends; the whole is the stored bundle.
    let mut rest = Vec::new();
    std::io::Read::read_to_end(&mut reader, &mut rest).unwrap();
    prefix.extend_from_slice(&rest);
    let status = wait(&client, &job);
    let stored = client
        .fetcher(data.join("cache"))
        .fetch(&client.bundle_url(status.bundle.as_ref().unwrap()))
        .unwrap();
    assert!(
        prefix == stored.bytes,
        "streamed bytes differ from the stored bundle"
    );
    assert!(decode(&prefix).unwrap().drt.is_some());
    drop(server);
    let _ = std::fs::remove_dir_all(&data);
}

#[test]
fn sigterm_drains_and_exits_cleanly() {
    let data = data_dir("sigterm");
    let mut server = Server::start(&data, None);
    let client = server.client();
    let scene = client.create_scene(&scene_text("cornell")).unwrap().id;
    let job = client.submit_bake(&scene, fast_settings()).unwrap().id;
    wait(&client, &job);
    // An open event stream must not hold the shutdown up.
    let events = client.events(&job).unwrap();
    let status = Command::new("kill")
        .args(["-TERM", &server.child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let start = Instant::now();
    let exit = loop {
        if let Some(exit) = server.child.try_wait().unwrap() {
            break exit;
        }
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "server did not exit"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(exit.success(), "{exit:?}");
    assert!(events.count() <= 2);
    // Restarted on the same data, the finished bake is still there.
    let server = Server::spawn(data.clone(), None);
    assert_eq!(
        server.client().bake_status(&job).unwrap().state,
        JobState::Succeeded
    );
    drop(server);
    let _ = std::fs::remove_dir_all(&data);
}
