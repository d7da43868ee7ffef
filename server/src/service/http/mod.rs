//! The HTTP layer: routes, shared state and the tower middleware (request ids, tracing,
//! timeouts, body limits). Handlers translate between HTTP and the [`JobQueue`]/[`BlobStore`]
//! traits; they do no light-transport work and run file and CPU work with `spawn_blocking`,
//! every call into the traits included (the store's methods touch files; the local queue's
//! lock is held while a job record is written, the farm's reaches NATS): a slow disk then holds
//! a blocking thread, never one of the runtime's two workers, which the request timeouts need.
//!
//! # Layout
//! - [`auth`]: the calling team; [`error`]: the error response.
//! - [`assets`], [`scenes`], [`bakes`], [`events`], [`bundles`], [`bake_bundle`] (a bundle
//!   streamed while it is written), [`evaluate`] (a bake's bundle applied to lights): the `/v1`
//!   resources; [`bake_list`], [`scene_list`]: the team's bakes and scenes, newest first, paged
//!   by [`paging`]; [`preview`]: a finished bake lit by a light set, as glTF.
//! - [`ops`]: health, readiness, metrics, shapes; [`openapi`]: `/openapi.json`.
//! - [`dashboard`]: the web dashboard at `/` (embedded files; it only calls the API).

pub mod assets;
pub mod auth;
pub mod bake_bundle;
pub mod bake_list;
pub mod bakes;
pub mod bundles;
pub mod dashboard;
pub mod error;
pub mod evaluate;
pub mod events;
pub mod openapi;
pub mod ops;
pub mod paging;
pub mod preview;
pub mod scene_list;
pub mod scenes;

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use axum::extract::DefaultBodyLimit;
use axum::http::{HeaderName, Request, StatusCode};
use axum::routing::{get, post};
use axum::Router;
use tokio::sync::watch;
use tower_http::compression::CompressionLayer;
use tower_http::request_id::{
    MakeRequestId, PropagateRequestIdLayer, RequestId, SetRequestIdLayer,
};
use tower_http::timeout::TimeoutLayer;
use tower_http::trace::TraceLayer;

use super::config::ServiceConfig;
use super::jobs::JobQueue;
use super::store::BlobStore;

/// What every handler can reach.
#[derive(Clone)]
pub struct AppState {
    pub config: Arc<ServiceConfig>,
    pub store: Arc<dyn BlobStore>,
    pub jobs: Arc<dyn JobQueue>,
    pub operator_cache: PathBuf,
    pub ready: Arc<AtomicBool>,
    /// Becomes true when the server begins to shut down.
    pub shutdown: watch::Receiver<bool>,
}

/// Request ids `<process start>-<counter>`, unique per process.
#[derive(Clone)]
struct SequentialRequestId {
    prefix: Arc<str>,
    next: Arc<AtomicU64>,
}

impl MakeRequestId for SequentialRequestId {
    fn make_request_id<B>(&mut self, _: &Request<B>) -> Option<RequestId> {
        let n = self.next.fetch_add(1, Ordering::Relaxed);
        format!("{}-{n}", self.prefix)
            .parse()
            .ok()
            .map(RequestId::new)
    }
}

const REQUEST_ID: HeaderName = HeaderName::from_static("x-request-id");

/// The whole API.
pub fn router(state: AppState) -> Router {
    let limits = &state.config.limits;
    let started = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    let ids = SequentialRequestId {
        prefix: format!("{started:x}").into(),
        next: Arc::new(AtomicU64::new(1)),
    };
    let api = Router::new()
        .route("/v1/assets", post(assets::upload_asset))
        .route(
            "/v1/scenes",
            get(scene_list::list_scenes).post(scenes::create_scene),
        )
        .route(
            "/v1/bakes",
            get(bake_list::list_bakes).post(bakes::submit_bake),
        )
        .route(
            "/v1/bakes/{id}",
            get(bakes::bake_status).delete(bakes::cancel_bake),
        )
        .route("/v1/bakes/{id}/events", get(events::bake_events))
        .route(
            "/v1/bakes/{id}/evaluate",
            // RESULT.json is text: compressed when the caller asks (80.6 MB at 1,000 blocks).
            post(evaluate::evaluate_bake).layer(CompressionLayer::new()),
        )
        .route("/v1/bakes/{id}/preview.glb", post(preview::preview_glb))
        .route(
            "/v1/bakes/{id}/bundle",
            get(bake_bundle::stream_bake_bundle),
        )
        .route("/v1/bundles/{hash}", get(bundles::get_bundle))
        .route("/v1/shapes", get(ops::list_shapes))
        .route("/healthz", get(ops::healthz))
        .route("/readyz", get(ops::readyz))
        .route("/metrics", get(ops::metrics))
        .route("/openapi.json", get(openapi::serve_openapi))
        .merge(dashboard::routes())
        .layer(DefaultBodyLimit::max(limits.max_body_bytes));
    api.with_state(state.clone())
        .layer(axum::middleware::from_fn(error::hide_internal_detail))
        .layer(TimeoutLayer::with_status_code(
            StatusCode::REQUEST_TIMEOUT,
            Duration::from_secs(limits.request_timeout_seconds),
        ))
        .layer(PropagateRequestIdLayer::new(REQUEST_ID))
        .layer(
            TraceLayer::new_for_http().make_span_with(|request: &Request<_>| {
                let id = request
                    .headers()
                    .get(REQUEST_ID)
                    .and_then(|v| v.to_str().ok())
                    .unwrap_or("-");
                tracing::info_span!("request", id, method = %request.method(), uri = %request.uri())
            }),
        )
        .layer(SetRequestIdLayer::new(REQUEST_ID, ids))
}
