//! `GET /v1/scenes`: the scenes the calling team stored, newest first (by when the team first
//! stored each), in pages with a `next` link ([`super::paging`]), each with the summary
//! `POST /v1/scenes` answers with.
//!
//! Invariant: only scenes granted to the team are listed; a scene the store has since trimmed
//! is left out of its page rather than failing the listing.

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::Json;
use serde::Deserialize;
use utoipa::IntoParams;

use lightfarm_proto::api::{ApiError, SceneList};
use lightfarm_proto::scene::Scene;

use super::auth::Caller;
use super::error::{blocking, ApiFailure};
use super::paging::{page, page_request};
use super::AppState;
use crate::service::scene_inputs::scene_summary;
use crate::service::store::BlobKind;

/// Query of `GET /v1/scenes`.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct SceneListQuery {
    /// Scenes per page (default 50).
    #[param(minimum = 1, maximum = 200)]
    pub limit: Option<u32>,
    /// Where the page starts: the `cursor` of a previous page's `next` link.
    #[param(pattern = "^[0-9a-f]{80}$")]
    pub cursor: Option<String>,
}

/// List the team's scenes.
#[utoipa::path(
    get,
    path = "/v1/scenes",
    tag = "scenes",
    params(SceneListQuery),
    responses(
        (status = 200, description = "One page, newest first", body = SceneList),
        (status = 400, description = "Bad `limit` or `cursor`", body = ApiError),
    ),
    security(("bearer" = []))
)]
pub async fn list_scenes(
    State(state): State<AppState>,
    Caller(team): Caller,
    query: Result<Query<SceneListQuery>, QueryRejection>,
) -> Result<Json<SceneList>, ApiFailure> {
    let Query(query) = query.map_err(ApiFailure::bad_query)?;
    let (limit, cursor) = page_request(query.limit, query.cursor.as_deref())?;
    let store = state.store.clone();
    let (scenes, next) = blocking(move || {
        let granted = store
            .granted(&team, BlobKind::Scene)
            .map_err(|e| ApiFailure::internal("store", e))?;
        let items = granted
            .into_iter()
            .map(|(id, at)| (at, id.clone(), id))
            .collect();
        let (ids, next) = page(items, cursor.as_ref(), limit);
        let mut scenes = Vec::with_capacity(ids.len());
        for id in ids {
            let Some(bytes) = store
                .get(BlobKind::Scene, &id)
                .map_err(|e| ApiFailure::internal("store", e))?
            else {
                continue;
            };
            let scene = std::str::from_utf8(&bytes)
                .ok()
                .and_then(|text| Scene::from_json(text).ok())
                .ok_or_else(|| ApiFailure::internal("stored scene", &id))?;
            scenes.push(scene_summary(id, &scene));
        }
        Ok((scenes, next))
    })
    .await?;
    let next = next.map(|c| format!("/v1/scenes?limit={limit}&cursor={}", c.encode()));
    Ok(Json(SceneList { scenes, next }))
}
