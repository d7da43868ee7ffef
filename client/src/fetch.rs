//! Fetching an operator bundle over HTTP at level load (feature `fetch`; `fetch-tls` adds https).
//!
//! [`BundleFetcher`] owns one cache directory. Per URL it keeps up to three files, named by a
//! 64-bit FNV-1a hash of the URL (`<key>`, 16 hex digits; a file-name key, not a security
//! measure: each file also records its full URL and one whose URL differs is ignored and
//! replaced):
//!
//! - `<key>.bundle`: a complete body with its `ETag` (a short text header, then the bytes).
//!   Sent back as `If-None-Match`; `304 Not Modified` returns it without a download.
//! - `<key>.part`: the body bytes received so far of an unfinished download, and
//!   `<key>.part.meta`, the URL and strong `ETag` of the response they came from. The next fetch
//!   asks for the rest with `Range: bytes=<len>-` and `If-Range: <etag>`: a `206` whose
//!   `Content-Range` starts at `<len>` is appended, a `200` (the resource changed) starts over.
//!
//! Invariants:
//! - `<key>.bundle` only ever holds bytes that passed [`crate::decode`]; it is written to a
//!   temporary file, synced and renamed, so it is complete or absent. A cached file that no
//!   longer decodes (disk damage) is deleted and downloaded again rather than served.
//! - A body that fails [`crate::decode`] is deleted with its `.part` and reported as
//!   [`FetchError::Corrupt`]; nothing of it is cached.
//! - A received length that disagrees with `Content-Length` / `Content-Range` is never accepted.
//! - Only identity bodies are accepted: the fetcher asks for `Accept-Encoding: identity` and
//!   refuses any other `Content-Encoding` ([`FetchError::Encoding`]), since hashes, lengths and
//!   ranges all refer to the stored bytes.
//! - One fetcher (one process) per cache directory at a time; there is no cross-process lock.
//!
//! ```no_run
//! # fn load() -> Result<(), Box<dyn std::error::Error>> {
//! use lightfarm_client::{decode, BundleFetcher};
//! let fetcher = BundleFetcher::new("cache/bundles")
//!     .with_timeout(std::time::Duration::from_secs(10));
//! let fetched = fetcher.fetch("http://bake.example/v1/bundles/3f2a9c")?;
//! let bundle = decode(&fetched.bytes)?;
//! # let _ = bundle; Ok(()) }
//! ```

use std::fs::{self, File, OpenOptions};
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};
use std::time::Duration;

use lightfarm_proto::wire::checksum;

use crate::BundleError;

/// Default for [`BundleFetcher::with_timeout`].
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(30);

const CACHE_MAGIC: &str = "lightfarm-fetch-cache 1";
const PART_MAGIC: &str = "lightfarm-fetch-part 1";

/// Downloads bundles over HTTP into an on-disk cache, revalidating and resuming (see the
/// module documentation).
#[derive(Clone, Debug)]
pub struct BundleFetcher {
    cache_dir: PathBuf,
    timeout: Duration,
    agent: ureq::Agent,
    bearer: Option<String>,
}

/// A bundle's bytes as fetched. They passed [`crate::decode`] when they were stored.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Fetched {
    pub bytes: Vec<u8>,
    /// The `ETag` the server gave these bytes, if any.
    pub etag: Option<String>,
    /// True when the server answered `304 Not Modified` and the bytes came from the cache.
    pub from_cache: bool,
    /// Byte offset this download resumed from (0 for a whole download or a cache hit).
    pub resumed_from: u64,
}

/// Why a fetch failed. Every message names the URL or the cache file at fault.
#[derive(Debug, thiserror::Error)]
pub enum FetchError {
    /// No response: connection, DNS, TLS, timeout or protocol failure.
    #[error("GET {url}: {source}")]
    Http {
        url: String,
        #[source]
        source: ureq::Error,
    },
    /// The server answered with a status other than 200, 206 or 304.
    #[error("GET {url}: server answered HTTP {status}")]
    Status { url: String, status: u16 },
    /// The connection failed while the body was streaming. When the response had a strong
    /// `ETag`, the bytes received so far are kept and the next fetch resumes after them.
    #[error("GET {url}: transfer interrupted after {received} bytes of the body: {source}")]
    Interrupted {
        url: String,
        received: u64,
        #[source]
        source: io::Error,
    },
    /// The body's length disagrees with the length the server announced.
    #[error("GET {url}: received {received} bytes but the server announced {expected}")]
    Length {
        url: String,
        received: u64,
        expected: u64,
    },
    /// The server compressed the body; only identity bodies are accepted.
    #[error("GET {url}: unsupported Content-Encoding {encoding:?} (only identity is accepted)")]
    Encoding { url: String, encoding: String },
    /// A response that breaks the HTTP rules this fetcher relies on.
    #[error("GET {url}: {detail}")]
    Protocol { url: String, detail: String },
    /// The downloaded body is not a valid bundle; it was deleted and nothing was cached.
    #[error("GET {url}: downloaded body is not a valid bundle (deleted, not cached): {source}")]
    Corrupt {
        url: String,
        #[source]
        source: BundleError,
    },
    /// Reading or writing the cache directory failed.
    #[error("bundle cache {path}: {source}", path = path.display())]
    Cache {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
}

/// A complete cached body.
struct Cached {
    etag: Option<String>,
    bytes: Vec<u8>,
}

/// An unfinished download that can be resumed.
struct Part {
    etag: String,
    len: u64,
}

/// What one request achieved.
enum Outcome {
    Done(Fetched),
    /// The server could not continue the `.part` (416, or a `206` that does not fit it): drop
    /// it and ask for the whole body.
    Restart,
}

impl BundleFetcher {
    /// A fetcher caching under `cache_dir` (created on the first fetch) with
    /// [`DEFAULT_TIMEOUT`].
    pub fn new(cache_dir: impl Into<PathBuf>) -> BundleFetcher {
        BundleFetcher {
            cache_dir: cache_dir.into(),
            timeout: DEFAULT_TIMEOUT,
            agent: agent(DEFAULT_TIMEOUT),
            bearer: None,
        }
    }

    /// Sends `Authorization: Bearer <token>` with every request (a `lightfarm serve` with
    /// teams).
    pub fn with_bearer_token(mut self, token: impl Into<String>) -> BundleFetcher {
        self.bearer = Some(token.into());
        self
    }

    /// The longest wait for any one step: connecting, sending the request, the response
    /// headers, or the next piece of the body. It is not a deadline for the whole download,
    /// since a large bundle on a slow link may take longer and still be making progress.
    pub fn with_timeout(mut self, timeout: Duration) -> BundleFetcher {
        self.timeout = timeout;
        self.agent = agent(timeout);
        self
    }

    pub fn cache_dir(&self) -> &Path {
        &self.cache_dir
    }

    pub fn timeout(&self) -> Duration {
        self.timeout
    }

    /// Fetches the bundle at `url`: revalidates a cached copy with `If-None-Match`, resumes an
    /// interrupted download with `Range`/`If-Range`, otherwise downloads it whole. The bytes
    /// returned passed [`crate::decode`].
    pub fn fetch(&self, url: &str) -> Result<Fetched, FetchError> {
        fs::create_dir_all(&self.cache_dir).map_err(|e| cache_error(&self.cache_dir, e))?;
        let key = format!("{:016x}", checksum(url.as_bytes()));
        let files = Files {
            bundle: self.cache_dir.join(format!("{key}.bundle")),
            bundle_tmp: self.cache_dir.join(format!("{key}.bundle.tmp")),
            part: self.cache_dir.join(format!("{key}.part")),
            part_meta: self.cache_dir.join(format!("{key}.part.meta")),
            part_meta_tmp: self.cache_dir.join(format!("{key}.part.meta.tmp")),
        };
        let mut cached = files.load_cached(url)?;
        let mut part = files.load_part(url)?;
        loop {
            let resuming = part.is_some();
            match self.request(url, &files, &mut cached, part.take())? {
                Outcome::Done(fetched) => return Ok(fetched),
                // The next round asks for the whole body, so this repeats at most once.
                Outcome::Restart if resuming => files.discard_part()?,
                Outcome::Restart => {
                    return Err(FetchError::Protocol {
                        url: url.to_string(),
                        detail: "server refused a request that asked for no range".into(),
                    })
                }
            }
        }
    }

    /// One GET, with the conditional and range headers the cache state calls for.
    fn request(
        &self,
        url: &str,
        files: &Files,
        cached: &mut Option<Cached>,
        part: Option<Part>,
    ) -> Result<Outcome, FetchError> {
        let mut request = self.agent.get(url).header("Accept-Encoding", "identity");
        if let Some(token) = &self.bearer {
            request = request.header("Authorization", format!("Bearer {token}"));
        }
        if let Some(etag) = cached.as_ref().and_then(|c| c.etag.as_deref()) {
            request = request.header("If-None-Match", etag);
        }
        if let Some(p) = &part {
            request = request
                .header("Range", format!("bytes={}-", p.len))
                .header("If-Range", p.etag.as_str());
        }
        let response = request.call().map_err(|source| FetchError::Http {
            url: url.to_string(),
            source,
        })?;
        let header = |name: &str| {
            response
                .headers()
                .get(name)
                .and_then(|v| v.to_str().ok())
                .map(|s| s.trim().to_string())
        };
        let status = response.status().as_u16();
        let etag = header("etag");
        let protocol = |detail: &str| FetchError::Protocol {
            url: url.to_string(),
            detail: detail.to_string(),
        };
        match status {
            304 => {
                let Some(c) = cached.take() else {
                    return Err(protocol(
                        "304 Not Modified to a request without If-None-Match",
                    ));
                };
                // Whatever a `.part` held, the cached body is current.
                files.discard_part()?;
                return Ok(Outcome::Done(Fetched {
                    bytes: c.bytes,
                    etag: c.etag,
                    from_cache: true,
                    resumed_from: 0,
                }));
            }
            200 | 206 => {}
            416 if part.is_some() => return Ok(Outcome::Restart),
            _ => {
                return Err(FetchError::Status {
                    url: url.to_string(),
                    status,
                })
            }
        }
        if let Some(encoding) = header("content-encoding") {
            if !encoding.is_empty() && !encoding.eq_ignore_ascii_case("identity") {
                return Err(FetchError::Encoding {
                    url: url.to_string(),
                    encoding,
                });
            }
        }
        let body_length = response.body().content_length();
        let (offset, total, etag) = if status == 206 {
            let Some(p) = part else {
                return Err(protocol("206 Partial Content to a request without Range"));
            };
            let range = header("content-range")
                .as_deref()
                .and_then(parse_content_range);
            let fits = match range {
                Some((start, end, total)) => {
                    start == p.len
                        && total.is_none_or(|t| end.checked_add(1) == Some(t))
                        && body_length.is_none_or(|n| {
                            Some(n) == end.checked_add(1).and_then(|x| x.checked_sub(start))
                        })
                }
                None => false,
            };
            // If-Range already made the server compare ETags; re-check any it sends.
            if !fits || etag.as_ref().is_some_and(|e| *e != p.etag) {
                return Ok(Outcome::Restart);
            }
            let total = range.and_then(|(_, _, t)| t);
            (p.len, total, Some(p.etag))
        } else {
            // 200: the whole body, whether or not a range was asked for.
            files.discard_part()?;
            (0, body_length, etag)
        };
        let resumable = etag.as_deref().is_some_and(is_strong);
        if offset == 0 {
            let meta = meta_text(PART_MAGIC, url, etag.as_deref().filter(|_| resumable));
            write_atomically(
                &files.part_meta_tmp,
                &files.part_meta,
                meta.as_bytes(),
                false,
            )?;
        }
        let mut out = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&files.part)
            .map_err(|e| cache_error(&files.part, e))?;
        let mut reader = response.into_body().into_reader();
        let mut buf = vec![0u8; 64 * 1024];
        let mut received = offset;
        loop {
            match reader.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => {
                    out.write_all(&buf[..n])
                        .map_err(|e| cache_error(&files.part, e))?;
                    received += n as u64;
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(source) => {
                    drop(out);
                    if !resumable {
                        files.discard_part()?;
                    }
                    return Err(FetchError::Interrupted {
                        url: url.to_string(),
                        received,
                        source,
                    });
                }
            }
        }
        drop(out);
        if let Some(expected) = total {
            if received < expected && resumable {
                return Err(FetchError::Interrupted {
                    url: url.to_string(),
                    received,
                    source: io::ErrorKind::UnexpectedEof.into(),
                });
            }
            if received != expected {
                files.discard_part()?;
                return Err(FetchError::Length {
                    url: url.to_string(),
                    received,
                    expected,
                });
            }
        }
        let bytes = fs::read(&files.part).map_err(|e| cache_error(&files.part, e))?;
        if bytes.len() as u64 != received {
            files.discard_part()?;
            return Err(cache_error(
                &files.part,
                io::Error::other("changed on disk during the download"),
            ));
        }
        if let Err(source) = crate::decode(&bytes) {
            files.discard_part()?;
            return Err(FetchError::Corrupt {
                url: url.to_string(),
                source,
            });
        }
        match &etag {
            Some(e) => {
                let mut file = meta_text(CACHE_MAGIC, url, Some(e)).into_bytes();
                file.extend_from_slice(&bytes);
                write_atomically(&files.bundle_tmp, &files.bundle, &file, true)?;
            }
            // Without an ETag the body cannot be revalidated: keep no copy, and drop an older
            // one, which this response has just superseded.
            None => remove_if_present(&files.bundle)?,
        }
        files.discard_part()?;
        Ok(Outcome::Done(Fetched {
            bytes,
            etag,
            from_cache: false,
            resumed_from: offset,
        }))
    }
}

/// The cache files of one URL.
struct Files {
    bundle: PathBuf,
    bundle_tmp: PathBuf,
    part: PathBuf,
    part_meta: PathBuf,
    part_meta_tmp: PathBuf,
}

impl Files {
    /// The complete cached body of `url`, if there is one that still decodes. Anything else
    /// in its place (another URL with the same key, an old format, damage) is deleted.
    fn load_cached(&self, url: &str) -> Result<Option<Cached>, FetchError> {
        let Some(mut data) = read_if_present(&self.bundle)? else {
            return Ok(None);
        };
        if let Some((meta_url, etag, start)) = parse_meta(CACHE_MAGIC, &data) {
            if meta_url == url && crate::decode(&data[start..]).is_ok() {
                data.drain(..start);
                return Ok(Some(Cached { etag, bytes: data }));
            }
        }
        remove_if_present(&self.bundle)?;
        Ok(None)
    }

    /// The resumable download of `url`, if any: a non-empty `.part` whose sidecar names this
    /// URL and a strong ETag. Anything else is deleted.
    fn load_part(&self, url: &str) -> Result<Option<Part>, FetchError> {
        let len = match fs::metadata(&self.part) {
            Ok(m) => m.len(),
            Err(e) if e.kind() == io::ErrorKind::NotFound => 0,
            Err(e) => return Err(cache_error(&self.part, e)),
        };
        let meta = read_if_present(&self.part_meta)?;
        let etag = meta
            .as_deref()
            .and_then(|m| parse_meta(PART_MAGIC, m))
            .filter(|(meta_url, _, _)| meta_url == url)
            .and_then(|(_, etag, _)| etag)
            .filter(|e| is_strong(e));
        match etag {
            Some(etag) if len > 0 => Ok(Some(Part { etag, len })),
            _ => {
                self.discard_part()?;
                Ok(None)
            }
        }
    }

    fn discard_part(&self) -> Result<(), FetchError> {
        remove_if_present(&self.part)?;
        remove_if_present(&self.part_meta)
    }
}

pub(crate) fn agent(timeout: Duration) -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .user_agent(concat!("lightfarm-client/", env!("CARGO_PKG_VERSION")))
        .timeout_connect(Some(timeout))
        .timeout_send_request(Some(timeout))
        .timeout_recv_response(Some(timeout))
        .timeout_per_read(Some(timeout))
        .timeout_per_write(Some(timeout))
        .build()
        .into()
}

/// `If-Range` needs a strong validator; a weak one (`W/"…"`) cannot resume a download.
fn is_strong(etag: &str) -> bool {
    !etag.starts_with("W/")
}

/// `bytes <start>-<end>/<total or *>` → (start, end, total).
fn parse_content_range(value: &str) -> Option<(u64, u64, Option<u64>)> {
    let (unit, rest) = value.trim().split_once(' ')?;
    if !unit.eq_ignore_ascii_case("bytes") {
        return None;
    }
    let (range, total) = rest.trim().split_once('/')?;
    let (start, end) = range.split_once('-')?;
    let (start, end): (u64, u64) = (start.parse().ok()?, end.parse().ok()?);
    let total = match total {
        "*" => None,
        t => Some(t.parse().ok()?),
    };
    (start <= end && total.is_none_or(|t| end < t)).then_some((start, end, total))
}

/// The text header of a cache or sidecar file: magic, URL and ETag lines, then a blank line.
fn meta_text(magic: &str, url: &str, etag: Option<&str>) -> String {
    format!("{magic}\nurl {url}\netag {}\n\n", etag.unwrap_or(""))
}

/// Parses [`meta_text`] → (url, etag, offset of what follows). `None` for anything else.
fn parse_meta(magic: &str, data: &[u8]) -> Option<(String, Option<String>, usize)> {
    let end = data.windows(2).take(64 * 1024).position(|w| w == b"\n\n")?;
    let text = std::str::from_utf8(&data[..end]).ok()?;
    let mut lines = text.split('\n');
    if lines.next()? != magic {
        return None;
    }
    let url = lines.next()?.strip_prefix("url ")?.to_string();
    let etag = lines.next()?.strip_prefix("etag ")?;
    if lines.next().is_some() {
        return None;
    }
    let etag = (!etag.is_empty()).then(|| etag.to_string());
    Some((url, etag, end + 2))
}

/// Writes `tmp`, optionally syncs it, and renames it over `path`: `path` is old or new, never
/// partial.
fn write_atomically(tmp: &Path, path: &Path, bytes: &[u8], sync: bool) -> Result<(), FetchError> {
    let result = (|| {
        let mut file = File::create(tmp)?;
        file.write_all(bytes)?;
        if sync {
            file.sync_all()?;
        }
        drop(file);
        fs::rename(tmp, path)
    })();
    result.map_err(|e| {
        let _ = fs::remove_file(tmp);
        cache_error(path, e)
    })
}

fn read_if_present(path: &Path) -> Result<Option<Vec<u8>>, FetchError> {
    match fs::read(path) {
        Ok(data) => Ok(Some(data)),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(cache_error(path, e)),
    }
}

fn remove_if_present(path: &Path) -> Result<(), FetchError> {
    match fs::remove_file(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(cache_error(path, e)),
    }
}

fn cache_error(path: &Path, source: io::Error) -> FetchError {
    FetchError::Cache {
        path: path.to_path_buf(),
        source,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn content_range_parses_and_rejects() {
        assert_eq!(
            parse_content_range("bytes 100-999/1000"),
            Some((100, 999, Some(1000)))
        );
        assert_eq!(parse_content_range("bytes 0-9/*"), Some((0, 9, None)));
        assert_eq!(parse_content_range("bytes 10-9/100"), None);
        assert_eq!(parse_content_range("bytes 0-100/100"), None);
        assert_eq!(parse_content_range("items 0-9/10"), None);
        assert_eq!(parse_content_range("bytes */100"), None);
    }

    #[test]
    fn meta_round_trips_and_rejects_other_magic() {
        let mut data = meta_text(CACHE_MAGIC, "http://h/v1/bundles/a", Some("\"x\"")).into_bytes();
        data.extend_from_slice(b"\n\nbody");
        let (url, etag, start) = parse_meta(CACHE_MAGIC, &data).unwrap();
        assert_eq!(url, "http://h/v1/bundles/a");
        assert_eq!(etag.as_deref(), Some("\"x\""));
        assert_eq!(&data[start..], b"\n\nbody");
        assert!(parse_meta(PART_MAGIC, &data).is_none());
        let none = meta_text(PART_MAGIC, "u", None);
        assert_eq!(parse_meta(PART_MAGIC, none.as_bytes()).unwrap().1, None);
    }
}
