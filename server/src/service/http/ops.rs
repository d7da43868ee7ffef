//! Operations endpoints: `/healthz` (the process answers), `/readyz` (it takes bakes: the store
//! and runners are up and it is not shutting down), `/metrics` (Prometheus text) and
//! `GET /v1/shapes` (cached shape operators and how often the team's bakes used them).

use std::fmt::Write;
use std::sync::atomic::Ordering;

use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::IntoResponse;
use axum::Json;

use lightfarm_proto::api::{ApiError, ShapeEntry};

use super::auth::Caller;
use super::error::{blocking, ApiFailure};
use super::AppState;
use crate::bake::cache::shape::{ENTRY as SHAPE_ENTRY, LIGHTFIELD_ENTRY};

/// Liveness.
#[utoipa::path(get, path = "/healthz", tag = "ops", responses((status = 200, description = "ok")))]
pub async fn healthz() -> &'static str {
    "ok\n"
}

/// Readiness.
#[utoipa::path(get, path = "/readyz", tag = "ops", responses(
    (status = 200, description = "ready"),
    (status = 503, description = "starting or shutting down"),
))]
pub async fn readyz(State(state): State<AppState>) -> (StatusCode, &'static str) {
    if state.ready.load(Ordering::SeqCst) && !*state.shutdown.borrow() {
        (StatusCode::OK, "ready\n")
    } else {
        (StatusCode::SERVICE_UNAVAILABLE, "not ready\n")
    }
}

/// Prometheus metrics.
#[utoipa::path(get, path = "/metrics", tag = "ops", responses((status = 200, description = "Prometheus text format", content_type = "text/plain")))]
pub async fn metrics(State(state): State<AppState>) -> Result<impl IntoResponse, ApiFailure> {
    // The queue's lock is held while a job record is written to disk: take both off the runtime.
    let (jobs, store) = (state.jobs.clone(), state.store.clone());
    let (q, s) = blocking(move || Ok((jobs.metrics(), store.stats()))).await?;
    let mut text = String::new();
    let mut gauge = |name: &str, help: &str, kind: &str, lines: Vec<(String, f64)>| {
        let _ = writeln!(text, "# HELP {name} {help}\n# TYPE {name} {kind}");
        for (labels, value) in lines {
            let _ = writeln!(text, "{name}{labels} {value}");
        }
    };
    gauge(
        "lightfarm_queue_depth",
        "Bakes waiting to run.",
        "gauge",
        vec![(String::new(), q.depth as f64)],
    );
    gauge(
        "lightfarm_bakes",
        "Bakes by state.",
        "gauge",
        q.by_state
            .iter()
            .map(|(st, n)| (format!("{{state=\"{}\"}}", st.name()), *n as f64))
            .collect(),
    );
    gauge(
        "lightfarm_stage_seconds_total",
        "Seconds spent per bake stage, summed over finished bakes.",
        "counter",
        q.stage_seconds
            .iter()
            .map(|(stage, sec)| (format!("{{stage=\"{stage}\"}}"), *sec))
            .collect(),
    );
    gauge(
        "lightfarm_cache_hits_total",
        "Cache hits: whole bakes answered from an earlier identical bake, shape operators read from the operator cache.",
        "counter",
        vec![
            ("{cache=\"bake\"}".into(), q.bake_cache_hits as f64),
            ("{cache=\"shape\"}".into(), q.shape_cache_hits as f64),
        ],
    );
    gauge(
        "lightfarm_cache_misses_total",
        "Cache misses: bakes queued, shape operators computed.",
        "counter",
        vec![
            ("{cache=\"bake\"}".into(), q.bake_cache_misses as f64),
            ("{cache=\"shape\"}".into(), q.shape_cache_misses as f64),
        ],
    );
    gauge(
        "lightfarm_store_bytes",
        "Bytes in the blob store (assets, scenes, bundles).",
        "gauge",
        vec![(String::new(), s.bytes as f64)],
    );
    gauge(
        "lightfarm_store_blobs",
        "Blobs in the store.",
        "gauge",
        vec![(String::new(), s.blobs as f64)],
    );
    gauge(
        "lightfarm_store_corrupt_dropped_total",
        "Blobs found not matching their hash and dropped.",
        "counter",
        vec![(String::new(), s.corrupt_dropped as f64)],
    );
    gauge(
        "lightfarm_store_trimmed_total",
        "Blobs trimmed to keep the store within its budget.",
        "counter",
        vec![(String::new(), s.trimmed as f64)],
    );
    Ok(([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], text))
}

/// Cached shape operators.
#[utoipa::path(
    get,
    path = "/v1/shapes",
    tag = "shapes",
    responses(
        (status = 200, body = Vec<ShapeEntry>),
        (status = 401, description = "No or unknown token", body = ApiError),
    ),
    security(("bearer" = []))
)]
pub async fn list_shapes(
    State(state): State<AppState>,
    Caller(team): Caller,
) -> Result<Json<Vec<ShapeEntry>>, ApiFailure> {
    let jobs = state.jobs.clone();
    let dir = state.operator_cache.clone();
    let entries = blocking(move || {
        let uses = jobs.shape_uses(&team);
        let mut entries = Vec::new();
        let listing = match std::fs::read_dir(&dir) {
            Ok(l) => l,
            Err(_) => return Ok(entries),
        };
        for entry in listing.flatten() {
            let name = entry.file_name().to_string_lossy().to_string();
            let Some(key) = name
                .strip_suffix(SHAPE_ENTRY.extension)
                .and_then(|n| n.strip_suffix('.'))
            else {
                continue;
            };
            // The operators and, beside them, the openings' lightfields.
            let bytes = entry.metadata().map(|m| m.len()).unwrap_or(0)
                + std::fs::metadata(dir.join(LIGHTFIELD_ENTRY.relative_path(key)))
                    .map(|m| m.len())
                    .unwrap_or(0);
            entries.push(ShapeEntry {
                key: key.to_string(),
                bytes,
                uses: uses.get(key).copied().unwrap_or(0),
            });
        }
        entries.sort_by(|a, b| b.uses.cmp(&a.uses).then(a.key.cmp(&b.key)));
        Ok(entries)
    })
    .await?;
    Ok(Json(entries))
}
