//! `lightfarm_client::fetch` against a small HTTP/1.1 server on 127.0.0.1 that plays the bake
//! service's `GET /v1/bundles/{hash}`: strong ETag, `If-None-Match` → 304, `Range: bytes=N-`
//! with `If-Range` → 206, and failure modes (drop the connection after K body bytes, corrupt
//! body, compressed body, wrong `Content-Range`, stall). Every test owns its server and cache
//! directory. The client's `fetch` feature comes from this crate's dev-dependency on it.

use std::io::{BufRead, BufReader, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use lightfarm_client::{BundleFetcher, FetchError};
use lightfarm_proto::bundle::{Layout, Matrix, SurfaceInfo};
use lightfarm_proto::testing::one_block_bundle;

const PATH: &str = "/v1/bundles/level1";

/// A small valid bundle (one block of `n` texels, rank 8) whose values depend on `seed`.
fn bundle_bytes(seed: u32) -> Vec<u8> {
    let n = 256;
    let r = 8;
    let value = |i: usize| ((i as u32).wrapping_mul(2654435761) ^ seed) as f32 / u32::MAX as f32;
    let matrix = |rows: usize, cols: usize, salt: usize| Matrix {
        rows: rows as u32,
        cols: cols as u32,
        data: (0..rows * cols).map(|i| value(i + salt)).collect(),
    };
    let layout = Layout {
        scene_name: format!("fetch-test-{seed}"),
        surfaces: vec![SurfaceInfo {
            name: "block:a/-y".into(),
            texel_offset: 0,
            texel_count: n as u32,
        }],
        positions: (0..n).map(|i| [i as f32 * 0.1, 0.0, value(i)]).collect(),
        normals: vec![[0.0, 1.0, 0.0]; n],
        albedo: (0..n).map(|i| [value(i), 0.5, 0.5]).collect(),
        texel_size: vec![[0.1, 0.1]; n],
        rects: vec![],
        triangles: vec![],
    };
    let key = format!("shape-{seed}");
    let bundle = one_block_bundle(layout, "a", &key, matrix(n, r, 0), matrix(r, n, 7));
    // Stored raw (no zstd) so the body is large enough to cut mid-transfer.
    let (bytes, _) = bundle.encode_with(&lightfarm_proto::bundle::EncodeOptions {
        zstd_level: 0,
        ..Default::default()
    });
    lightfarm_client::decode(&bytes).expect("the test bundle is valid");
    bytes
}

/// What the server serves at [`PATH`] and how it misbehaves.
struct State {
    body: Vec<u8>,
    etag: String,
    /// Send only this many body bytes of the next 200/206, then close (one-shot).
    drop_after: Option<usize>,
    content_encoding: Option<String>,
    /// Answer the next range request with a `Content-Range` one byte off (one-shot).
    wrong_range_start: bool,
    /// Wait this long before answering anything.
    stall: Option<Duration>,
    log: Vec<Logged>,
}

/// A request as the server saw it and the status it answered.
#[derive(Clone, Debug)]
struct Logged {
    path: String,
    headers: Vec<(String, String)>,
    status: u16,
}

impl Logged {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }
}

struct Server {
    addr: std::net::SocketAddr,
    state: Arc<Mutex<State>>,
}

impl Server {
    fn start(body: Vec<u8>, etag: &str) -> Server {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let state = Arc::new(Mutex::new(State {
            body,
            etag: etag.to_string(),
            drop_after: None,
            content_encoding: None,
            wrong_range_start: false,
            stall: None,
            log: Vec::new(),
        }));
        let shared = state.clone();
        // Lives as long as the test process; each connection is one bounded exchange.
        std::thread::spawn(move || {
            for stream in listener.incoming().flatten() {
                let state = shared.clone();
                std::thread::spawn(move || serve(stream, &state));
            }
        });
        Server { addr, state }
    }

    fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.addr)
    }

    fn set(&self, f: impl FnOnce(&mut State)) {
        f(&mut self.state.lock().unwrap());
    }

    fn log(&self) -> Vec<Logged> {
        self.state.lock().unwrap().log.clone()
    }
}

/// One request, one response, then close (`Connection: close`).
fn serve(stream: TcpStream, state: &Mutex<State>) {
    stream
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let mut reader = BufReader::new(stream.try_clone().unwrap());
    let mut line = String::new();
    if reader.read_line(&mut line).unwrap_or(0) == 0 {
        return;
    }
    let path = line.split_whitespace().nth(1).unwrap_or("").to_string();
    let mut headers = Vec::new();
    loop {
        let mut h = String::new();
        if reader.read_line(&mut h).unwrap_or(0) == 0 || h.trim().is_empty() {
            break;
        }
        if let Some((k, v)) = h.split_once(':') {
            headers.push((k.trim().to_string(), v.trim().to_string()));
        }
    }
    let stall = state.lock().unwrap().stall;
    if let Some(d) = stall {
        std::thread::sleep(d);
    }
    let mut logged = Logged {
        path: path.clone(),
        headers,
        status: 0,
    };
    let (status, extra, body) = {
        let mut s = state.lock().unwrap();
        let etag = s.etag.clone();
        let len = s.body.len();
        let range_start = logged
            .header("range")
            .and_then(|r| r.strip_prefix("bytes="))
            .and_then(|r| r.strip_suffix('-'))
            .and_then(|n| n.parse::<usize>().ok());
        let if_range_ok = logged.header("if-range").is_none_or(|e| e == etag);
        let mut extra = vec![format!("ETag: {etag}")];
        if let Some(enc) = &s.content_encoding {
            extra.push(format!("Content-Encoding: {enc}"));
        }
        let (status, mut body) = if path != PATH {
            extra.clear();
            (404, b"no such bundle".to_vec())
        } else if logged.header("if-none-match") == Some(etag.as_str()) {
            (304, Vec::new())
        } else if let (Some(start), true) = (range_start, if_range_ok) {
            if start >= len {
                extra.push(format!("Content-Range: bytes */{len}"));
                (416, Vec::new())
            } else {
                let shown = if std::mem::take(&mut s.wrong_range_start) {
                    start + 1
                } else {
                    start
                };
                extra.push(format!("Content-Range: bytes {shown}-{}/{len}", len - 1));
                (206, s.body[start..].to_vec())
            }
        } else {
            (200, s.body.clone())
        };
        logged.status = status;
        s.log.push(logged);
        // Content-Length announces the whole body; a drop sends only its first K bytes.
        extra.push(format!("Content-Length: {}", body.len()));
        if matches!(status, 200 | 206) {
            if let Some(k) = s.drop_after.take() {
                body.truncate(k);
            }
        }
        (status, extra, body)
    };
    let mut out = stream;
    let mut head = format!("HTTP/1.1 {status} X\r\nConnection: close\r\n");
    for h in extra {
        head.push_str(&h);
        head.push_str("\r\n");
    }
    head.push_str("\r\n");
    let _ = out.write_all(head.as_bytes());
    let _ = out.write_all(&body);
    let _ = out.flush();
    let _ = out.shutdown(Shutdown::Both);
}

/// A fresh, empty cache directory for one test.
fn cache_dir(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lf-fetch-{test}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// File names in the cache directory, sorted.
fn files(dir: &PathBuf) -> Vec<String> {
    let mut names: Vec<String> = match std::fs::read_dir(dir) {
        Ok(entries) => entries
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect(),
        Err(_) => Vec::new(),
    };
    names.sort();
    names
}

fn part_len(dir: &PathBuf) -> Option<u64> {
    files(dir)
        .iter()
        .find(|n| n.ends_with(".part"))
        .map(|n| std::fs::metadata(dir.join(n)).unwrap().len())
}

#[test]
fn downloads_then_revalidates_with_304() {
    let body = bundle_bytes(1);
    let server = Server::start(body.clone(), "\"v1\"");
    let dir = cache_dir("revalidate");
    let fetcher = BundleFetcher::new(&dir);
    let url = server.url(PATH);

    let first = fetcher.fetch(&url).unwrap();
    assert_eq!(first.bytes, body);
    assert_eq!(first.etag.as_deref(), Some("\"v1\""));
    assert!(!first.from_cache);
    assert_eq!(first.resumed_from, 0);
    let names = files(&dir);
    assert_eq!(names.len(), 1, "{names:?}");
    assert!(names[0].ends_with(".bundle"), "{names:?}");

    let second = fetcher.fetch(&url).unwrap();
    assert!(second.from_cache);
    assert_eq!(second.bytes, body);
    assert_eq!(second.etag.as_deref(), Some("\"v1\""));

    let log = server.log();
    assert_eq!(log.len(), 2);
    assert_eq!(log[0].path, PATH);
    assert_eq!(log[0].header("if-none-match"), None);
    assert_eq!(log[0].status, 200);
    assert_eq!(log[1].header("if-none-match"), Some("\"v1\""));
    assert_eq!(log[1].header("range"), None);
    assert_eq!(log[1].status, 304);
    assert_eq!(log[1].header("accept-encoding"), Some("identity"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn dropped_transfer_resumes_from_exactly_k() {
    let body = bundle_bytes(2);
    let k = 10_000;
    assert!(body.len() > 2 * k);
    let server = Server::start(body.clone(), "\"v2\"");
    let dir = cache_dir("resume");
    let fetcher = BundleFetcher::new(&dir);
    let url = server.url(PATH);

    server.set(|s| s.drop_after = Some(k));
    match fetcher.fetch(&url) {
        Err(FetchError::Interrupted { received, .. }) => assert_eq!(received, k as u64),
        other => panic!("expected an interrupted transfer, got {other:?}"),
    }
    assert_eq!(part_len(&dir), Some(k as u64));
    assert!(!files(&dir).iter().any(|n| n.ends_with(".bundle")));

    let resumed = fetcher.fetch(&url).unwrap();
    assert_eq!(resumed.resumed_from, k as u64);
    assert_eq!(resumed.bytes, body);
    assert!(!resumed.from_cache);
    let log = server.log();
    assert_eq!(log.len(), 2);
    let expected_range = format!("bytes={k}-");
    assert_eq!(log[1].header("range"), Some(expected_range.as_str()));
    assert_eq!(log[1].header("if-range"), Some("\"v2\""));
    assert_eq!(log[1].status, 206);
    assert_eq!(part_len(&dir), None, "{:?}", files(&dir));

    // The resumed body was cached like any other.
    let again = fetcher.fetch(&url).unwrap();
    assert!(again.from_cache);
    assert_eq!(again.bytes, body);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn changed_etag_mid_resume_restarts_from_zero() {
    let old = bundle_bytes(3);
    let new = bundle_bytes(4);
    assert_ne!(old, new);
    let k = 5_000;
    let server = Server::start(old, "\"old\"");
    let dir = cache_dir("etag-change");
    let fetcher = BundleFetcher::new(&dir);
    let url = server.url(PATH);

    server.set(|s| s.drop_after = Some(k));
    assert!(matches!(
        fetcher.fetch(&url),
        Err(FetchError::Interrupted { .. })
    ));
    assert_eq!(part_len(&dir), Some(k as u64));

    server.set(|s| {
        s.body = new.clone();
        s.etag = "\"new\"".into();
    });
    let fetched = fetcher.fetch(&url).unwrap();
    assert_eq!(fetched.resumed_from, 0);
    assert_eq!(fetched.bytes, new);
    assert_eq!(fetched.etag.as_deref(), Some("\"new\""));
    let log = server.log();
    let expected_range = format!("bytes={k}-");
    assert_eq!(log[1].header("range"), Some(expected_range.as_str()));
    assert_eq!(log[1].header("if-range"), Some("\"old\""));
    assert_eq!(log[1].status, 200);
    assert_eq!(part_len(&dir), None);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn range_that_does_not_fit_the_part_restarts_from_zero() {
    let body = bundle_bytes(5);
    let k = 4_000;
    let server = Server::start(body.clone(), "\"v5\"");
    let dir = cache_dir("bad-range");
    let fetcher = BundleFetcher::new(&dir);
    let url = server.url(PATH);

    server.set(|s| s.drop_after = Some(k));
    assert!(fetcher.fetch(&url).is_err());
    server.set(|s| s.wrong_range_start = true);
    let fetched = fetcher.fetch(&url).unwrap();
    assert_eq!(fetched.resumed_from, 0);
    assert_eq!(fetched.bytes, body);
    let log = server.log();
    assert_eq!(log.len(), 3);
    assert_eq!(log[1].status, 206);
    assert_eq!(log[2].header("range"), None);
    assert_eq!(log[2].status, 200);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn corrupt_body_is_rejected_and_nothing_is_cached() {
    let mut body = bundle_bytes(6);
    let last = body.len() - 1;
    body[last] ^= 0x55; // inside the last section's payload: its checksum fails
    assert!(lightfarm_client::decode(&body).is_err());
    let server = Server::start(body, "\"bad\"");
    let dir = cache_dir("corrupt");
    let fetcher = BundleFetcher::new(&dir);
    let url = server.url(PATH);

    let err = fetcher.fetch(&url).unwrap_err();
    assert!(matches!(err, FetchError::Corrupt { .. }), "{err:?}");
    assert!(err.to_string().contains(&url), "{err}");
    assert_eq!(files(&dir), Vec::<String>::new());

    // Nothing was cached, so the next request is unconditional.
    let _ = fetcher.fetch(&url);
    let log = server.log();
    assert_eq!(log[1].header("if-none-match"), None);
    assert_eq!(log[1].header("range"), None);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn damaged_cache_file_is_downloaded_again() {
    let body = bundle_bytes(7);
    let server = Server::start(body.clone(), "\"v7\"");
    let dir = cache_dir("damaged-cache");
    let fetcher = BundleFetcher::new(&dir);
    let url = server.url(PATH);
    fetcher.fetch(&url).unwrap();

    let name = files(&dir).pop().unwrap();
    let path = dir.join(name);
    let mut stored = std::fs::read(&path).unwrap();
    let last = stored.len() - 1;
    stored[last] ^= 0x55;
    std::fs::write(&path, stored).unwrap();

    let fetched = fetcher.fetch(&url).unwrap();
    assert!(!fetched.from_cache);
    assert_eq!(fetched.bytes, body);
    let log = server.log();
    assert_eq!(log[1].header("if-none-match"), None);
    assert_eq!(log[1].status, 200);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn missing_bundle_names_the_url() {
    let server = Server::start(bundle_bytes(8), "\"v8\"");
    let dir = cache_dir("missing");
    let url = server.url("/v1/bundles/missing");
    let err = BundleFetcher::new(&dir).fetch(&url).unwrap_err();
    assert!(
        matches!(err, FetchError::Status { status: 404, .. }),
        "{err:?}"
    );
    assert!(err.to_string().contains(&url), "{err}");
    assert_eq!(server.log()[0].path, "/v1/bundles/missing");
    assert_eq!(files(&dir), Vec::<String>::new());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn compressed_body_is_refused() {
    let server = Server::start(bundle_bytes(9), "\"v9\"");
    server.set(|s| s.content_encoding = Some("gzip".into()));
    let dir = cache_dir("encoding");
    let url = server.url(PATH);
    let err = BundleFetcher::new(&dir).fetch(&url).unwrap_err();
    assert!(matches!(err, FetchError::Encoding { .. }), "{err:?}");
    let message = err.to_string();
    assert!(
        message.contains(&url) && message.contains("gzip"),
        "{message}"
    );
    assert_eq!(files(&dir), Vec::<String>::new());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn stalled_server_times_out() {
    let server = Server::start(bundle_bytes(10), "\"v10\"");
    server.set(|s| s.stall = Some(Duration::from_secs(4)));
    let dir = cache_dir("stall");
    let fetcher = BundleFetcher::new(&dir).with_timeout(Duration::from_millis(300));
    let start = Instant::now();
    let err = fetcher.fetch(&server.url(PATH)).unwrap_err();
    let elapsed = start.elapsed();
    assert!(matches!(err, FetchError::Http { .. }), "{err:?}");
    assert!(elapsed < Duration::from_secs(3), "took {elapsed:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
