//! `POST /v1/bakes/{id}/preview.glb`: a finished bake's bundle lit by the posted light set, as
//! binary glTF (`crate::export`): what the dashboard's 3D view loads, and what any glTF viewer
//! opens.
//!
//! Invariants: the handler only translates (team-scoped lookup, body checks, status codes); the
//! evaluation and glTF assembly run in `crate::export` on a blocking thread. A bake that has not
//! succeeded is a 409 naming its state.

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{Path, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};

use lightfarm_client::Bundle;
use lightfarm_proto::api::{ApiError, JobState, PreviewLight, PreviewRequest};
use lightfarm_proto::lights::LightSet;

use super::auth::Caller;
use super::error::{blocking, body_failure, ApiFailure};
use super::AppState;
use crate::export::{export_glb, ExportError, ExportOptions, LightMode};
use crate::service::store::BlobKind;

/// The export options a preview request asks for.
fn options(request: &PreviewRequest) -> ExportOptions {
    ExportOptions {
        mode: match request.light {
            PreviewLight::Lit => LightMode::Lit,
            PreviewLight::Direct => LightMode::Direct,
            PreviewLight::Indirect => LightMode::Indirect,
        },
        bounces: request.bounces.count(),
    }
}

/// A finished bake lit by a light set, as glTF.
#[utoipa::path(
    post,
    path = "/v1/bakes/{id}/preview.glb",
    tag = "bakes",
    params(("id" = String, Path, description = "Bake id")),
    request_body = PreviewRequest,
    responses(
        (status = 200, description = "Binary glTF: meshes with their lightmaps, point lights", content_type = "model/gltf-binary"),
        (status = 404, description = "No such bake for this team", body = ApiError),
        (status = 409, description = "The bake has not succeeded (no bundle yet)", body = ApiError),
        (status = 413, description = "Body over the limit", body = ApiError),
        (status = 422, description = "Invalid request or light set, or a pose without a DNRT grid", body = ApiError),
    ),
    security(("bearer" = []))
)]
pub async fn preview_glb(
    State(state): State<AppState>,
    Caller(team): Caller,
    Path(id): Path<String>,
    body: Result<Bytes, BytesRejection>,
) -> Result<Response, ApiFailure> {
    let body = body.map_err(|r| body_failure(r, state.config.limits.max_body_bytes))?;
    let status = state
        .jobs
        .status(&team, &id)
        .ok_or_else(|| ApiFailure::not_found("bake", &id))?;
    let request: PreviewRequest = serde_json::from_slice(&body)
        .map_err(|e| ApiFailure::unprocessable(format!("preview request: {e}")))?;
    let lights = serde_json::to_string(&request.lights).expect("lights serialise");
    let lights = LightSet::from_json(&lights)
        .map_err(|e| ApiFailure::unprocessable(format!("lights: {e}")))?;
    let (JobState::Succeeded, Some(hash)) = (status.state, status.bundle.clone()) else {
        return Err(ApiFailure::new(
            StatusCode::CONFLICT,
            format!(
                "bake {id} is {}: a preview needs its finished bundle",
                status.state.name()
            ),
        ));
    };
    let store = state.store.clone();
    let options = options(&request);
    let glb = blocking(move || {
        let bytes = store
            .get(BlobKind::Bundle, &hash)
            .map_err(|e| ApiFailure::internal("store", e))?
            .ok_or_else(|| ApiFailure::not_found("bundle", &hash))?;
        let bundle =
            Bundle::decode(&bytes).map_err(|e| ApiFailure::internal("stored bundle", e))?;
        export_glb(bundle, &lights, options)
            .map(|(glb, _)| glb)
            .map_err(|e| match e {
                ExportError::Evaluate(message) => ApiFailure::unprocessable(message),
                other => ApiFailure::internal("export", other),
            })
    })
    .await?;
    Ok((
        [
            (header::CONTENT_TYPE, "model/gltf-binary"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        glb,
    )
        .into_response())
}
