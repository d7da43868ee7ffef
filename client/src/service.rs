//! The bake service's `/v1` API from an editor plugin, a CI job or a test (feature `fetch`):
//! upload assets and scenes, submit bakes, watch their server-sent events, cancel them. Bundles
//! themselves are downloaded with [`crate::BundleFetcher`] (cache, revalidation, resume), which
//! [`ServiceClient::fetcher`] sets up for this server.
//!
//! Invariants: blocking calls on one `ureq` agent with per-step timeouts (not whole-request
//! deadlines, so an event stream can stay open); every non-2xx answer becomes
//! [`ServiceError::Api`] with the server's message and, for 429, its `Retry-After`.

use std::io::{BufRead, BufReader, Read};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use lightfarm_proto::api::{AssetCreated, BakeEvent, BakeStatus, SceneCreated, SubmitBake};

use crate::fetch::{agent, BundleFetcher};

/// What went wrong talking to the service.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// No HTTP answer (connection refused, timeout…).
    #[error("{method} {url}: {source}")]
    Transport {
        method: &'static str,
        url: String,
        #[source]
        source: ureq::Error,
    },
    /// The server answered with an error status.
    #[error("{method} {url}: HTTP {status}: {message}")]
    Api {
        method: &'static str,
        url: String,
        status: u16,
        message: String,
        /// Seconds, from `Retry-After` (429).
        retry_after: Option<u64>,
    },
    /// A 2xx answer whose body is not what the API promises.
    #[error("{method} {url}: unexpected body: {detail}")]
    Body {
        method: &'static str,
        url: String,
        detail: String,
    },
    /// [`ServiceClient::wait`] gave up.
    #[error("bake {id}: still {state} after {seconds:.0} s")]
    Timeout {
        id: String,
        state: String,
        seconds: f64,
    },
}

impl ServiceError {
    /// The HTTP status of an [`ServiceError::Api`] answer.
    pub fn status(&self) -> Option<u16> {
        match self {
            ServiceError::Api { status, .. } => Some(*status),
            _ => None,
        }
    }
}

/// A client of one `lightfarm serve`.
#[derive(Clone, Debug)]
pub struct ServiceClient {
    base: String,
    token: Option<String>,
    agent: ureq::Agent,
}

/// A decoded HTTP answer: status, headers we use, body.
struct Answer {
    status: u16,
    location: Option<String>,
    body: Vec<u8>,
}

impl ServiceClient {
    /// A client of the server at `base` (e.g. `http://127.0.0.1:8080`), no token.
    pub fn new(base: impl Into<String>) -> ServiceClient {
        ServiceClient {
            base: base.into().trim_end_matches('/').to_string(),
            token: None,
            agent: agent(Duration::from_secs(60)),
        }
    }

    /// Sends `Authorization: Bearer <token>`.
    pub fn with_token(mut self, token: impl Into<String>) -> ServiceClient {
        self.token = Some(token.into());
        self
    }

    pub fn base(&self) -> &str {
        &self.base
    }

    /// The URL of a bundle.
    pub fn bundle_url(&self, hash: &str) -> String {
        format!("{}/v1/bundles/{hash}", self.base)
    }

    /// A bundle fetcher for this server (with this client's token), caching under `cache_dir`.
    pub fn fetcher(&self, cache_dir: impl Into<PathBuf>) -> BundleFetcher {
        let fetcher = BundleFetcher::new(cache_dir);
        match &self.token {
            Some(t) => fetcher.with_bearer_token(t.clone()),
            None => fetcher,
        }
    }

    fn call(
        &self,
        method: &'static str,
        path: &str,
        body: Option<(&str, &[u8])>,
    ) -> Result<Answer, ServiceError> {
        let url = format!("{}{path}", self.base);
        let auth = self.token.as_ref().map(|t| format!("Bearer {t}"));
        let transport = |source| ServiceError::Transport {
            method,
            url: url.clone(),
            source,
        };
        let response = match (method, body) {
            ("POST", Some((content_type, bytes))) => {
                let mut r = self.agent.post(&url).header("Content-Type", content_type);
                if let Some(a) = &auth {
                    r = r.header("Authorization", a);
                }
                r.send(bytes).map_err(transport)?
            }
            ("DELETE", _) => {
                let mut r = self.agent.delete(&url);
                if let Some(a) = &auth {
                    r = r.header("Authorization", a);
                }
                r.call().map_err(transport)?
            }
            _ => {
                let mut r = self.agent.get(&url);
                if let Some(a) = &auth {
                    r = r.header("Authorization", a);
                }
                r.call().map_err(transport)?
            }
        };
        let status = response.status().as_u16();
        let header = |name: &str| {
            response
                .headers()
                .get(name)
                .and_then(|v| v.to_str().ok())
                .map(str::to_string)
        };
        let location = header("location");
        let retry_after = header("retry-after").and_then(|v| v.trim().parse().ok());
        let mut body = Vec::new();
        response
            .into_body()
            .into_reader()
            .read_to_end(&mut body)
            .map_err(|e| transport(ureq::Error::Io(e)))?;
        if !(200..300).contains(&status) {
            let message = serde_json::from_slice::<lightfarm_proto::api::ApiError>(&body)
                .map(|e| e.error)
                .unwrap_or_else(|_| String::from_utf8_lossy(&body).into_owned());
            return Err(ServiceError::Api {
                method,
                url,
                status,
                message,
                retry_after,
            });
        }
        Ok(Answer {
            status,
            location,
            body,
        })
    }

    fn json<T: serde::de::DeserializeOwned>(
        &self,
        method: &'static str,
        path: &str,
        body: Option<(&str, &[u8])>,
    ) -> Result<T, ServiceError> {
        let answer = self.call(method, path, body)?;
        serde_json::from_slice(&answer.body).map_err(|e| ServiceError::Body {
            method,
            url: format!("{}{path}", self.base),
            detail: e.to_string(),
        })
    }

    /// `POST /v1/assets`: a GLB, glTF or OBJ mesh; returns its hash for scene mesh paths.
    pub fn upload_asset(&self, bytes: &[u8]) -> Result<AssetCreated, ServiceError> {
        self.json(
            "POST",
            "/v1/assets",
            Some(("application/octet-stream", bytes)),
        )
    }

    /// `POST /v1/scenes`: a scene description (JSON text).
    pub fn create_scene(&self, scene_json: &str) -> Result<SceneCreated, ServiceError> {
        self.json(
            "POST",
            "/v1/scenes",
            Some(("application/json", scene_json.as_bytes())),
        )
    }

    /// `POST /v1/bakes`: returns the job's status; `cached` is true when an identical bake had
    /// already finished (HTTP 200 rather than 202).
    pub fn submit_bake(
        &self,
        scene: &str,
        settings: serde_json::Value,
    ) -> Result<BakeStatus, ServiceError> {
        let request = SubmitBake {
            scene: scene.to_string(),
            settings,
        };
        let body = serde_json::to_vec(&request).expect("request serialises");
        let answer = self.call("POST", "/v1/bakes", Some(("application/json", &body)))?;
        let url = format!("{}/v1/bakes", self.base);
        let status: BakeStatus =
            serde_json::from_slice(&answer.body).map_err(|e| ServiceError::Body {
                method: "POST",
                url: url.clone(),
                detail: e.to_string(),
            })?;
        let expected_location = format!("/v1/bakes/{}", status.id);
        if answer.status == 202 && answer.location.as_deref() != Some(&expected_location) {
            return Err(ServiceError::Body {
                method: "POST",
                url,
                detail: format!("202 without Location {expected_location}"),
            });
        }
        Ok(status)
    }

    /// `GET /v1/bakes/{id}`.
    pub fn bake_status(&self, id: &str) -> Result<BakeStatus, ServiceError> {
        self.json("GET", &format!("/v1/bakes/{id}"), None)
    }

    /// `DELETE /v1/bakes/{id}`.
    pub fn cancel_bake(&self, id: &str) -> Result<BakeStatus, ServiceError> {
        self.json("DELETE", &format!("/v1/bakes/{id}"), None)
    }

    /// Polls until the bake reaches a final state, at most `timeout`.
    pub fn wait(&self, id: &str, timeout: Duration) -> Result<BakeStatus, ServiceError> {
        let start = Instant::now();
        loop {
            let status = self.bake_status(id)?;
            if status.state.is_final() {
                return Ok(status);
            }
            if start.elapsed() > timeout {
                return Err(ServiceError::Timeout {
                    id: id.to_string(),
                    state: status.state.name().to_string(),
                    seconds: start.elapsed().as_secs_f64(),
                });
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// `GET /v1/bakes/{id}/events`: the bake's events as they happen; the iterator ends after
    /// a final state (or when the server closes the stream).
    pub fn events(&self, id: &str) -> Result<BakeEvents, ServiceError> {
        let url = format!("{}/v1/bakes/{id}/events", self.base);
        let mut request = self.agent.get(&url).header("Accept", "text/event-stream");
        if let Some(t) = &self.token {
            request = request.header("Authorization", format!("Bearer {t}"));
        }
        let response = request.call().map_err(|source| ServiceError::Transport {
            method: "GET",
            url: url.clone(),
            source,
        })?;
        let status = response.status().as_u16();
        if status != 200 {
            let mut body = String::new();
            let _ = response.into_body().into_reader().read_to_string(&mut body);
            return Err(ServiceError::Api {
                method: "GET",
                url,
                status,
                message: body,
                retry_after: None,
            });
        }
        Ok(BakeEvents {
            lines: BufReader::new(Box::new(response.into_body().into_reader())),
            finished: false,
        })
    }
}

/// Server-sent events of one bake, parsed.
pub struct BakeEvents {
    lines: BufReader<Box<dyn Read + Send>>,
    finished: bool,
}

impl Iterator for BakeEvents {
    type Item = BakeEvent;

    fn next(&mut self) -> Option<BakeEvent> {
        if self.finished {
            return None;
        }
        let mut data = String::new();
        loop {
            let mut line = String::new();
            match self.lines.read_line(&mut line) {
                Ok(0) | Err(_) => {
                    self.finished = true;
                    return None;
                }
                Ok(_) => {}
            }
            let line = line.trim_end_matches(['\r', '\n']);
            if line.is_empty() {
                if data.is_empty() {
                    continue; // a keep-alive comment's end, or stray blank line
                }
                let event: BakeEvent = match serde_json::from_str(&data) {
                    Ok(e) => e,
                    Err(_) => {
                        data.clear();
                        continue;
                    }
                };
                if let BakeEvent::State { state, .. } = &event {
                    if state.is_final() {
                        self.finished = true;
                    }
                }
                return Some(event);
            }
            if let Some(rest) = line.strip_prefix("data:") {
                if !data.is_empty() {
                    data.push('\n');
                }
                data.push_str(rest.strip_prefix(' ').unwrap_or(rest));
            }
        }
    }
}
