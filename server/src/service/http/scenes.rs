//! `POST /v1/scenes`: a scene description (`lightfarm.scene/1`) whose mesh paths name uploaded
//! assets is validated with the CLI's own checks and stored under the hash of its canonical
//! JSON.
//!
//! Invariant: a stored scene is valid and every mesh it names is an asset the team can see, in
//! the `"<hash>.<ext>"` form the bake lays out as files.

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::State;
use axum::http::StatusCode;
use axum::Json;

use lightfarm_proto::api::{ApiError, SceneCreated};
use lightfarm_proto::scene::Scene;

use super::auth::Caller;
use super::error::{blocking, body_failure, ApiFailure};
use super::AppState;
use crate::service::scene_inputs::{canonical_json, rewrite_meshes, scene_summary, AssetFormat};
use crate::service::store::BlobKind;

/// Validate and store a scene.
#[utoipa::path(
    post,
    path = "/v1/scenes",
    tag = "scenes",
    request_body(content = Object, description = "A `lightfarm.scene/1` document (schema: components.schemas.Scene); mesh paths are asset hashes", content_type = "application/json"),
    responses(
        (status = 201, description = "Stored (or already stored)", body = SceneCreated),
        (status = 401, description = "No or unknown token", body = ApiError),
        (status = 413, description = "Body over the limit", body = ApiError),
        (status = 422, description = "Invalid scene, with the CLI's message", body = ApiError),
    ),
    security(("bearer" = []))
)]
pub async fn create_scene(
    State(state): State<AppState>,
    Caller(team): Caller,
    body: Result<Bytes, BytesRejection>,
) -> Result<(StatusCode, Json<SceneCreated>), ApiFailure> {
    let body = body.map_err(|r| body_failure(r, state.config.limits.max_body_bytes))?;
    let store = state.store.clone();
    let created = blocking(move || {
        let text = std::str::from_utf8(&body)
            .map_err(|e| ApiFailure::unprocessable(format!("scene: not UTF-8: {e}")))?;
        // Errors of the JSON itself come from the scene parser, worded as the CLI words them.
        let mut document: serde_json::Value = serde_json::from_str(text).map_err(|_| {
            ApiFailure::unprocessable(Scene::from_json(text).unwrap_err().to_string())
        })?;
        rewrite_meshes(&mut document, |object, hash| {
            if !store.visible(&team, BlobKind::Asset, hash) {
                return Err(format!("{object}: mesh {hash} is not an uploaded asset"));
            }
            let bytes = store
                .get(BlobKind::Asset, hash)
                .map_err(|e| e.to_string())?
                .ok_or_else(|| format!("{object}: asset {hash} is gone; upload it again"))?;
            let format = AssetFormat::detect(&bytes)
                .ok_or_else(|| format!("{object}: asset {hash} is not a mesh"))?;
            Ok(format!("{hash}.{}", format.extension()))
        })
        .map_err(ApiFailure::unprocessable)?;
        let scene = Scene::from_json(&document.to_string())
            .map_err(|e| ApiFailure::unprocessable(e.to_string()))?;
        let bytes = canonical_json(&scene);
        let id = store
            .put(BlobKind::Scene, &bytes)
            .map_err(|e| ApiFailure::internal("store", e))?;
        store
            .grant(&team, BlobKind::Scene, &id)
            .map_err(|e| ApiFailure::internal("store", e))?;
        Ok(scene_summary(id, &scene))
    })
    .await?;
    Ok((StatusCode::CREATED, Json(created)))
}
