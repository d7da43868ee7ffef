//! End-to-end tests of the bake farm (`lightfarm serve --farm`, `lightfarm worker --farm`) on a
//! real NATS JetStream server: one `nats-server` on a free loopback port, two serve replicas and
//! three workers as processes (the crate's `lightfarm-test-server` binary, which is `lightfarm
//! serve` and, with `worker` first, `lightfarm worker`).
//!
//! `farm_survives_a_dead_worker_and_a_restarted_replica`: the maze with its pillars is baked
//! through replica A while replica B streams the events; a worker is SIGKILLed while it runs a
//! unit (JetStream delivers the unit again to another worker), replica A is SIGKILLed and
//! restarted mid-bake; the bundle is byte-identical to the embedded bake. Then a second bake is
//! cancelled on replica B and the workers stop its units.
//!
//! `farm_worker_keeps_its_operator_cache_within_budget`: a worker with a tiny `--cache-bytes`
//! trims its local operator cache after each unit and bake (so later units and the assembler
//! fetch earlier units' files again), ends within the budget, and still bakes the embedded
//! bundle byte for byte.
//!
//! `farm_keeps_teams_apart_and_bounds_its_queue`: with team tokens and no workers, another
//! team's bake and scene are 404 and submissions beyond `queue_capacity` are 429.
//!
//! Skipped (passing, with a message) only when the `nats-server` binary is absent; `.ci/run`
//! installs it, so CI always runs it.

use std::io::{BufRead, BufReader};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use lightfarm_client::ServiceClient;
use lightfarm_proto::api::{BakeEvent, JobState};
use lightfarm_proto::scene::Scene;
use lightfarm_server::bake::pipeline::encoding::encode_options;
use lightfarm_server::bake::progress::NoProgress;
use lightfarm_server::bake::{bake, BakeOptions};
use lightfarm_tests::{scene_dir, spawn_listening};
use serde_json::json;

const TEST_SERVER: &str = env!("CARGO_BIN_EXE_lightfarm-test-server");
/// Longest wait for anything in these tests (a bound, not a timing assertion).
const PATIENCE: Duration = Duration::from_secs(240);

fn nats_server() -> Option<PathBuf> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path)
        .chain([
            "/usr/sbin".into(),
            "/usr/local/bin".into(),
            "/usr/bin".into(),
        ])
        .map(|dir| dir.join("nats-server"))
        .find(|p| p.is_file())
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// Kills the child when dropped.
struct Process(Child);

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start_nats(binary: &Path, dir: &Path) -> (Process, String) {
    let port = free_port();
    let child = Command::new(binary)
        .args(["-js", "-a", "127.0.0.1", "-p", &port.to_string(), "-sd"])
        .arg(dir)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(Instant::now() < deadline, "nats-server did not listen");
        std::thread::sleep(Duration::from_millis(50));
    }
    (Process(child), format!("nats://127.0.0.1:{port}"))
}

/// A `lightfarm serve --farm` replica.
struct Replica {
    process: Process,
    addr: String,
}

impl Replica {
    fn start(farm: &str, data: &Path) -> Replica {
        Replica::start_with(farm, data, None)
    }

    fn start_with(farm: &str, data: &Path, config: Option<&Path>) -> Replica {
        let mut command = Command::new(TEST_SERVER);
        command
            .args(["--addr", "127.0.0.1:0", "--farm", farm, "--data"])
            .arg(data);
        if let Some(config) = config {
            command.arg("--config").arg(config);
        }
        let (child, addr) = spawn_listening(&mut command);
        Replica {
            process: Process(child),
            addr,
        }
    }

    fn client(&self) -> ServiceClient {
        ServiceClient::new(&self.addr)
    }

    fn kill9(self) {
        drop(self.process); // SIGKILL on unix, then reaped
    }
}

/// A fresh directory `<tmp>/<name>-<pid>` and a JetStream server under it (the server stops
/// when the returned process drops), with its URL; None, after saying so, when `nats-server` is
/// not installed (`.ci/run` installs it, so CI always runs the farm tests).
fn farm(name: &str) -> Option<(PathBuf, Process, String)> {
    let Some(nats) = nats_server() else {
        eprintln!(
            "SKIPPED: the nats-server binary is not installed (apt-get install nats-server; \
             .ci/run installs it)"
        );
        return None;
    };
    let root = std::env::temp_dir().join(format!("{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).unwrap();
    let (process, url) = start_nats(&nats, &root.join("nats"));
    Some((root, process, url))
}

/// What a worker printed, with the worker's index.
struct Line {
    worker: usize,
    text: String,
    at: Instant,
}

fn start_worker(farm: &str, cache: &Path, index: usize, lines: mpsc::Sender<Line>) -> Process {
    start_worker_with(farm, cache, index, lines, &[])
}

fn start_worker_with(
    farm: &str,
    cache: &Path,
    index: usize,
    lines: mpsc::Sender<Line>,
    extra: &[&str],
) -> Process {
    let mut child = Command::new(TEST_SERVER)
        .args(["worker", "--farm", farm, "--threads", "1", "--cache"])
        .arg(cache)
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    std::thread::spawn(move || {
        for text in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = lines.send(Line {
                worker: index,
                text,
                at: Instant::now(),
            });
        }
    });
    Process(child)
}

/// Waits for the first line matching `wanted`.
fn wait_line(lines: &mpsc::Receiver<Line>, wanted: impl Fn(&Line) -> bool) -> Line {
    let deadline = Instant::now() + PATIENCE;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        let line = lines
            .recv_timeout(left)
            .expect("no matching worker line in time");
        if wanted(&line) {
            return line;
        }
    }
}

/// `(job, unit)` of a "started unit" line.
fn started_unit(text: &str) -> Option<(String, String)> {
    let rest = text.split_once(": started unit ")?.1;
    let (unit, rest) = rest.split_once(" of job ")?;
    let job = rest.split_whitespace().next()?;
    Some((job.to_string(), unit.to_string()))
}

fn maze_settings(rays: u32) -> serde_json::Value {
    json!({"texels_per_face": 4, "rays_per_texel": rays})
}

/// The embedded bake of the maze with the same settings, encoded as the service does.
fn embedded_bundle(rays: u32) -> Vec<u8> {
    let dir = scene_dir("maze");
    let mut scene =
        Scene::from_json(&std::fs::read_to_string(dir.join("scene.json")).unwrap()).unwrap();
    scene.settings.texels_per_face = 4;
    scene.settings.rays_per_texel = rays;
    let (bundle, _) = bake(&scene, &dir, &BakeOptions::default(), &NoProgress).unwrap();
    bundle.encode_with(&encode_options(&scene.settings, None)).0
}

#[test]
fn farm_survives_a_dead_worker_and_a_restarted_replica() {
    let Some((root, _nats, url)) = farm("lightfarm-farm") else {
        return;
    };

    let replica_a = Replica::start(&url, &root.join("a"));
    let replica_b = Replica::start(&url, &root.join("b"));
    let (line_sender, lines) = mpsc::channel();
    let mut workers: Vec<Option<Process>> = (0..3)
        .map(|i| {
            Some(start_worker(
                &url,
                &root.join(format!("worker-{i}")),
                i,
                line_sender.clone(),
            ))
        })
        .collect();
    for _ in 0..3 {
        wait_line(&lines, |l| l.text.contains(": ready"));
    }

    let scene_text = std::fs::read_to_string(scene_dir("maze").join("scene.json")).unwrap();
    let scene = replica_a.client().create_scene(&scene_text).unwrap();
    let submitted = replica_a
        .client()
        .submit_bake(&scene.id, maze_settings(64))
        .unwrap();
    assert!(!submitted.cached);

    // Replica B watches the bake it did not take.
    let watcher = {
        let client = replica_b.client();
        let id = submitted.id.clone();
        std::thread::spawn(move || client.events(&id).unwrap().collect::<Vec<BakeEvent>>())
    };

    // A worker dies in the middle of a unit: another one takes the unit again. Units of this
    // test are short, so the victim may have finished its unit before the signal landed (its
    // "finished" line then comes out of the pipe); then the next unit's worker is killed.
    let mut killed = 0;
    loop {
        let first = wait_line(&lines, |l| {
            workers[l.worker].is_some()
                && started_unit(&l.text).is_some_and(|(j, _)| j == submitted.id)
        });
        let (job, unit) = started_unit(&first.text).unwrap();
        workers[first.worker].take(); // SIGKILL
        killed += 1;
        let killed_at = Instant::now();
        let finished = format!(": finished unit {unit} of job {job}");
        let next = wait_line(&lines, |l| {
            (l.worker != first.worker
                && started_unit(&l.text).is_some_and(|(j, u)| j == job && u == unit))
                || (l.worker == first.worker && l.text.contains(&finished))
        });
        if next.worker != first.worker {
            eprintln!(
                "unit {unit} delivered again {:.1} s after its worker was killed",
                next.at.saturating_duration_since(killed_at).as_secs_f64()
            );
            break;
        }
        assert!(killed < 2, "two workers finished their unit before SIGKILL");
    }

    // Replica A dies and comes back mid-bake: the job lives in the farm, not in the replica.
    replica_a.kill9();
    let replica_a = Replica::start(&url, &root.join("a"));
    let status = replica_a.client().bake_status(&submitted.id).unwrap();
    assert_eq!(status.id, submitted.id);
    let done = replica_a.client().wait(&submitted.id, PATIENCE).unwrap();
    assert_eq!(done.state, JobState::Succeeded, "{:?}", done.error);
    let hash = done.bundle.clone().unwrap();

    let events = watcher.join().unwrap();
    assert!(
        events
            .iter()
            .any(|e| matches!(e, BakeEvent::Stage { stage, .. } if stage.starts_with("units"))),
        "{events:?}"
    );
    let Some(BakeEvent::State {
        state: JobState::Succeeded,
        bundle: Some(streamed),
        ..
    }) = events.last()
    else {
        panic!(
            "replica B's stream did not end with success: {:?}",
            events.last()
        );
    };
    assert_eq!(streamed, &hash);

    // The farm's bundle, fetched from the other replica, is the embedded bake's, byte for byte.
    let fetched = replica_b
        .client()
        .fetcher(root.join("client-cache"))
        .fetch(&replica_b.client().bundle_url(&hash))
        .unwrap();
    assert!(
        fetched.bytes == embedded_bundle(64),
        "the farm's bundle differs from the embedded bake"
    );

    // The same bake again is answered from the finished job, on either replica.
    let again = replica_b
        .client()
        .submit_bake(&scene.id, maze_settings(64))
        .unwrap();
    assert!(again.cached);
    assert_eq!(again.bundle.as_deref(), Some(hash.as_str()));

    // Cancel on replica B stops a bake submitted on replica A, units included.
    let second = replica_a
        .client()
        .submit_bake(&scene.id, maze_settings(16384))
        .unwrap();
    let running = wait_line(&lines, |l| {
        started_unit(&l.text).is_some_and(|(j, _)| j == second.id)
    });
    let cancelled = replica_b.client().cancel_bake(&second.id).unwrap();
    assert_eq!(cancelled.state, JobState::Cancelled);
    wait_line(&lines, |l| {
        l.worker == running.worker
            && l.text.contains(": cancelled unit ")
            && l.text.contains(&second.id)
    });
    let status = replica_a.client().bake_status(&second.id).unwrap();
    assert_eq!(status.state, JobState::Cancelled);
    assert!(status.bundle.is_none());

    drop(workers);
    drop(replica_a);
    drop(replica_b);
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn farm_keeps_teams_apart_and_bounds_its_queue() {
    let Some((root, _nats, url)) = farm("lightfarm-farm-teams") else {
        return;
    };
    let config = root.join("farm.toml");
    std::fs::write(
        &config,
        "[limits]\nqueue_capacity = 2\n\
         [[teams]]\nname = \"red\"\ntoken = \"red-token\"\n\
         [[teams]]\nname = \"blue\"\ntoken = \"blue-token\"\n",
    )
    .unwrap();
    let replica = Replica::start_with(&url, &root.join("a"), Some(&config));
    let red = replica.client().with_token("red-token");
    let blue = replica.client().with_token("blue-token");

    let scene_text = std::fs::read_to_string(scene_dir("maze").join("scene.json")).unwrap();
    let scene = red.create_scene(&scene_text).unwrap().id;
    // No worker runs: the first two bakes wait, the third is refused.
    let mut accepted = Vec::new();
    for seed in 0..3 {
        match red.submit_bake(&scene, json!({"seed": seed, "texels_per_face": 4})) {
            Ok(status) => accepted.push(status.id),
            Err(lightfarm_client::ServiceError::Api {
                status: 429,
                retry_after,
                ..
            }) => assert!(retry_after.is_some_and(|s| s >= 1)),
            Err(e) => panic!("{e}"),
        }
    }
    assert_eq!(accepted.len(), 2);
    // The same bake again joins the waiting job instead of queueing another.
    let again = red
        .submit_bake(&scene, json!({"seed": 0, "texels_per_face": 4}))
        .unwrap();
    assert_eq!(again.id, accepted[0]);

    // Blue sees neither red's bake nor red's scene.
    assert_eq!(
        blue.bake_status(&accepted[0]).unwrap_err().status(),
        Some(404)
    );
    assert_eq!(
        blue.cancel_bake(&accepted[0]).unwrap_err().status(),
        Some(404)
    );
    assert_eq!(
        blue.submit_bake(&scene, json!({"texels_per_face": 4}))
            .unwrap_err()
            .status(),
        Some(404)
    );
    // The listings come from the farm's shared records: red's two bakes newest first, one page
    // of one at a time; blue lists nothing of red's.
    let list = |token: &str, path: &str| -> serde_json::Value {
        let agent: ureq::Agent = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .build()
            .into();
        let text = agent
            .get(format!("{}{path}", replica.addr))
            .header("Authorization", format!("Bearer {token}"))
            .call()
            .unwrap()
            .body_mut()
            .read_to_string()
            .unwrap();
        serde_json::from_str(&text).unwrap()
    };
    let first = list("red-token", "/v1/bakes?limit=1&state=queued");
    assert_eq!(first["bakes"][0]["id"], accepted[1].as_str(), "{first}");
    let second = list("red-token", first["next"].as_str().unwrap());
    assert_eq!(second["bakes"][0]["id"], accepted[0].as_str(), "{second}");
    assert!(second["next"].is_null());
    assert_eq!(list("blue-token", "/v1/bakes")["bakes"], json!([]));
    assert_eq!(
        list("red-token", "/v1/scenes")["scenes"][0]["id"],
        scene.as_str()
    );
    assert_eq!(list("blue-token", "/v1/scenes")["scenes"], json!([]));

    assert_eq!(
        red.bake_status(&accepted[1]).unwrap().state,
        JobState::Queued
    );
    let cancelled = red.cancel_bake(&accepted[1]).unwrap();
    assert_eq!(cancelled.state, JobState::Cancelled);

    drop(replica);
    let _ = std::fs::remove_dir_all(&root);
}

/// Bytes of the cache files under `dir` (one level of subdirectories, as the trim counts them;
/// writes in flight, named `.…`, left out).
fn cache_bytes(dir: &Path) -> u64 {
    let mut total = 0;
    let mut dirs = vec![(dir.to_path_buf(), 0)];
    while let Some((d, depth)) = dirs.pop() {
        let Ok(read) = std::fs::read_dir(&d) else {
            continue;
        };
        for entry in read.flatten() {
            let meta = entry.metadata().unwrap();
            if meta.is_dir() {
                if depth == 0 {
                    dirs.push((entry.path(), depth + 1));
                }
            } else if !entry.file_name().to_string_lossy().starts_with('.') {
                total += meta.len();
            }
        }
    }
    total
}

#[test]
fn farm_worker_keeps_its_operator_cache_within_budget() {
    let Some((root, _nats, url)) = farm("lightfarm-farm-trim") else {
        return;
    };
    let replica = Replica::start(&url, &root.join("a"));
    let (line_sender, lines) = mpsc::channel();
    let budget: u64 = 100_000;
    let worker_dir = root.join("worker");
    let _worker = start_worker_with(
        &url,
        &worker_dir,
        0,
        line_sender,
        &["--cache-bytes", &budget.to_string()],
    );
    wait_line(&lines, |l| l.text.contains(": ready"));

    let scene_text = std::fs::read_to_string(scene_dir("maze").join("scene.json")).unwrap();
    let scene = replica.client().create_scene(&scene_text).unwrap();
    // Every unit trims the cache after it, so later units and the assembler find earlier
    // units' files gone and fetch them again from the farm's store.
    let submitted = replica
        .client()
        .submit_bake(&scene.id, maze_settings(64))
        .unwrap();
    let done = replica.client().wait(&submitted.id, PATIENCE).unwrap();
    assert_eq!(done.state, JobState::Succeeded, "{:?}", done.error);
    let fetched = replica
        .client()
        .fetcher(root.join("client-cache"))
        .fetch(&replica.client().bundle_url(&done.bundle.unwrap()))
        .unwrap();
    assert!(
        fetched.bytes == embedded_bundle(64),
        "the trimmed worker's bundle differs from the embedded bake"
    );
    let trimmed = wait_line(&lines, |l| l.text.contains(": trimmed operator cache: "));
    eprintln!("{}", trimmed.text);
    assert!(
        trimmed.text.contains(&format!("(budget {budget})")),
        "{}",
        trimmed.text
    );
    // The coordinator trims after the bake; its line comes after the job's success.
    let deadline = Instant::now() + PATIENCE;
    while cache_bytes(&worker_dir.join("operators")) > budget {
        assert!(
            Instant::now() < deadline,
            "the worker's operator cache stayed at {} bytes, budget {budget}",
            cache_bytes(&worker_dir.join("operators"))
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    drop(replica);
    let _ = std::fs::remove_dir_all(&root);
}
