//! `/v1/bakes`: submit a bake, read its status, cancel it.
//!
//! Invariants: a submission is checked against the limits (texels, rays) with the effective
//! settings before anything is queued; an identical earlier bake is answered at once (`200`,
//! `cached: true`); a new or still-running one is `202 Accepted` with `Location`.

use axum::extract::rejection::JsonRejection;
use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::Json;

use lightfarm_proto::api::{ApiError, BakeStatus, JobState, SubmitBake};
use lightfarm_proto::scene::Scene;

use super::auth::Caller;
use super::error::{blocking, ApiFailure};
use super::AppState;
use crate::service::jobs::{BakeRequest, QueueError};
use crate::service::scene_inputs::{
    apply_overrides, asset_hash, bake_id, expected_stages, mesh_references, texel_count,
};
use crate::service::store::BlobKind;

/// Submit a bake.
#[utoipa::path(
    post,
    path = "/v1/bakes",
    tag = "bakes",
    request_body = SubmitBake,
    responses(
        (status = 200, description = "The same bake finished before: its status, at once", body = BakeStatus),
        (status = 202, description = "Queued (or already queued/running)", body = BakeStatus,
            headers(("Location" = String, description = "/v1/bakes/{id}"))),
        (status = 401, description = "No or unknown token", body = ApiError),
        (status = 404, description = "No such scene for this team", body = ApiError),
        (status = 422, description = "Invalid settings or over the texel/ray limits", body = ApiError),
        (status = 429, description = "Queue full; see Retry-After", body = ApiError),
    ),
    security(("bearer" = []))
)]
pub async fn submit_bake(
    State(state): State<AppState>,
    Caller(team): Caller,
    body: Result<Json<SubmitBake>, JsonRejection>,
) -> Result<(StatusCode, HeaderMap, Json<BakeStatus>), ApiFailure> {
    let Json(request) = body.map_err(|r| ApiFailure::unprocessable(r.body_text()))?;
    let store = state.store.clone();
    let jobs = state.jobs.clone();
    let limits = state.config.limits.clone();
    let status = blocking(move || {
        if !store.visible(&team, BlobKind::Scene, &request.scene) {
            return Err(ApiFailure::not_found("scene", &request.scene));
        }
        let bytes = store
            .get(BlobKind::Scene, &request.scene)
            .map_err(|e| ApiFailure::internal("store", e))?
            .ok_or_else(|| ApiFailure::not_found("scene", &request.scene))?;
        let text = std::str::from_utf8(&bytes).map_err(|e| ApiFailure::internal("scene", e))?;
        let scene = Scene::from_json(text).map_err(|e| ApiFailure::internal("stored scene", e))?;
        let scene =
            apply_overrides(&scene, &request.settings).map_err(ApiFailure::unprocessable)?;
        let texels = texel_count(&scene);
        if texels > limits.max_texels {
            return Err(ApiFailure::unprocessable(format!(
                "the bake has {texels} texels (texels_per_face {}); limits.max_texels is {}",
                scene.settings.texels_per_face, limits.max_texels
            )));
        }
        let rays = texels * scene.settings.rays_per_texel as u64;
        if rays > limits.max_rays_per_bake {
            return Err(ApiFailure::unprocessable(format!(
                "the bake traces {rays} rays ({texels} texels × rays_per_texel {}); \
                 limits.max_rays_per_bake is {}",
                scene.settings.rays_per_texel, limits.max_rays_per_bake
            )));
        }
        let mut inputs = vec![(BlobKind::Scene, request.scene.clone())];
        for (_, mesh) in mesh_references(&scene) {
            if let Some(hash) = asset_hash(&mesh) {
                inputs.push((BlobKind::Asset, hash.to_string()));
            }
        }
        let id = bake_id(&request.scene, &scene.settings);
        jobs.submit(BakeRequest {
            id,
            scene: request.scene,
            settings: request.settings,
            team,
            inputs,
            expected_stages: expected_stages(&scene),
        })
        .map_err(|e| match e {
            QueueError::Full { retry_after, .. } => ApiFailure {
                status: StatusCode::TOO_MANY_REQUESTS,
                message: e.to_string(),
                retry_after: Some(retry_after),
            },
            QueueError::Io(_) => ApiFailure::internal("job queue", e),
        })
    })
    .await?;
    let mut headers = HeaderMap::new();
    let location = format!("/v1/bakes/{}", status.id);
    headers.insert(
        header::LOCATION,
        HeaderValue::from_str(&location).expect("hex id"),
    );
    let code = if status.state == JobState::Succeeded {
        StatusCode::OK
    } else {
        StatusCode::ACCEPTED
    };
    Ok((code, headers, Json(status)))
}

/// A bake's state, stage, progress and timings.
#[utoipa::path(
    get,
    path = "/v1/bakes/{id}",
    tag = "bakes",
    params(("id" = String, Path, description = "Bake id")),
    responses(
        (status = 200, body = BakeStatus),
        (status = 404, description = "No such bake for this team", body = ApiError),
    ),
    security(("bearer" = []))
)]
pub async fn bake_status(
    State(state): State<AppState>,
    Caller(team): Caller,
    Path(id): Path<String>,
) -> Result<Json<BakeStatus>, ApiFailure> {
    // The queue's lock is held while a job record is written to disk: wait for it off the
    // runtime.
    let (jobs, key) = (state.jobs.clone(), id.clone());
    blocking(move || Ok(jobs.status(&team, &key)))
        .await?
        .map(Json)
        .ok_or_else(|| ApiFailure::not_found("bake", &id))
}

/// Cancel a queued or running bake (the work stops within a second).
#[utoipa::path(
    delete,
    path = "/v1/bakes/{id}",
    tag = "bakes",
    params(("id" = String, Path, description = "Bake id")),
    responses(
        (status = 202, description = "Cancelled, or cancelling (watch the state)", body = BakeStatus),
        (status = 404, description = "No such bake for this team", body = ApiError),
    ),
    security(("bearer" = []))
)]
pub async fn cancel_bake(
    State(state): State<AppState>,
    Caller(team): Caller,
    Path(id): Path<String>,
) -> Result<(StatusCode, Json<BakeStatus>), ApiFailure> {
    let jobs = state.jobs.clone();
    let status = blocking(move || {
        jobs.cancel(&team, &id)
            .ok_or_else(|| ApiFailure::not_found("bake", &id))
    })
    .await?;
    Ok((StatusCode::ACCEPTED, Json(status)))
}
