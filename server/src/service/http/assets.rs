//! `POST /v1/assets`: a mesh (GLB, self-contained glTF or OBJ) is checked by loading it exactly
//! as a bake will, counted against `limits.max_triangles`, and stored under its content hash.
//!
//! Invariant: only meshes that load are stored, and only self-contained ones (a glTF that refers
//! to a file is refused, so a bake of the asset reads nothing but it); the load parses the body in
//! memory, off the async runtime.

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::State;
use axum::http::StatusCode;
use axum::Json;

use lightfarm_proto::api::{ApiError, AssetCreated};
use lightfarm_proto::scene::Transform;

use super::auth::Caller;
use super::error::{blocking, body_failure, ApiFailure};
use super::AppState;
use crate::bake::scene::mesh::load_mesh_bytes;
use crate::service::scene_inputs::AssetFormat;
use crate::service::store::{content_hash, BlobKind};

/// Upload a mesh asset.
#[utoipa::path(
    post,
    path = "/v1/assets",
    tag = "assets",
    request_body(content = Vec<u8>, description = "GLB, glTF (buffers and images embedded: data URIs or the GLB chunk; a URI naming a file is refused) or OBJ bytes", content_type = "application/octet-stream"),
    responses(
        (status = 201, description = "Stored (or already stored)", body = AssetCreated),
        (status = 401, description = "No or unknown token", body = ApiError),
        (status = 413, description = "Body or triangle count over the limit", body = ApiError),
        (status = 422, description = "Not a mesh that loads", body = ApiError),
    ),
    security(("bearer" = []))
)]
pub async fn upload_asset(
    State(state): State<AppState>,
    Caller(team): Caller,
    body: Result<Bytes, BytesRejection>,
) -> Result<(StatusCode, Json<AssetCreated>), ApiFailure> {
    let limit = state.config.limits.max_body_bytes;
    let body = body.map_err(|r| body_failure(r, limit))?;
    let format = AssetFormat::detect(&body)
        .ok_or_else(|| ApiFailure::unprocessable("asset: not GLB, glTF JSON or OBJ text"))?;
    let max_triangles = state.config.limits.max_triangles;
    let store = state.store.clone();
    let created = blocking(move || {
        let hash = content_hash(&body);
        let mesh = load_mesh_bytes(
            &format!("asset {hash}"),
            &format!("upload.{}", format.extension()),
            &body,
            format.mesh_format(),
            &Transform::default(),
        )
        .map_err(|e| ApiFailure::unprocessable(e.to_string()))?;
        let triangles = mesh.triangles.len() as u64;
        if triangles > max_triangles {
            return Err(ApiFailure::too_large(format!(
                "asset has {triangles} triangles; limits.max_triangles is {max_triangles}"
            )));
        }
        if triangles == 0 {
            return Err(ApiFailure::unprocessable(
                "asset: the mesh has no triangles",
            ));
        }
        store
            .put(BlobKind::Asset, &body)
            .and_then(|_| store.grant(&team, BlobKind::Asset, &hash))
            .map_err(|e| ApiFailure::internal("store", e))?;
        Ok(AssetCreated {
            hash,
            format: format.extension().to_string(),
            bytes: body.len() as u64,
            triangles,
        })
    })
    .await?;
    Ok((StatusCode::CREATED, Json(created)))
}
