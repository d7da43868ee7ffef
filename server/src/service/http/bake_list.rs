//! `GET /v1/bakes`: the calling team's bakes, newest first (by submission time), optionally of
//! one state, in pages with a `next` link ([`super::paging`]).
//!
//! Invariant: only the team's own bakes are listed (the job queue filters by owner); a farm
//! replica lists what every replica submitted, from the shared job records.

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::Json;
use serde::Deserialize;
use utoipa::IntoParams;

use lightfarm_proto::api::{ApiError, BakeList, JobState};

use super::auth::Caller;
use super::error::{blocking, ApiFailure};
use super::paging::{page, page_request};
use super::AppState;

/// Query of `GET /v1/bakes`.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct BakeListQuery {
    /// Only bakes in this state.
    pub state: Option<JobState>,
    /// Bakes per page (default 50).
    #[param(minimum = 1, maximum = 200)]
    pub limit: Option<u32>,
    /// Where the page starts: the `cursor` of a previous page's `next` link.
    #[param(pattern = "^[0-9a-f]{80}$")]
    pub cursor: Option<String>,
}

/// List the team's bakes.
#[utoipa::path(
    get,
    path = "/v1/bakes",
    tag = "bakes",
    params(BakeListQuery),
    responses(
        (status = 200, description = "One page, newest first", body = BakeList),
        (status = 400, description = "Bad `state`, `limit` or `cursor`", body = ApiError),
    ),
    security(("bearer" = []))
)]
pub async fn list_bakes(
    State(state): State<AppState>,
    Caller(team): Caller,
    query: Result<Query<BakeListQuery>, QueryRejection>,
) -> Result<Json<BakeList>, ApiFailure> {
    let Query(query) = query.map_err(ApiFailure::bad_query)?;
    let (limit, cursor) = page_request(query.limit, query.cursor.as_deref())?;
    let jobs = state.jobs.clone();
    let all = blocking(move || Ok(jobs.list(&team))).await?;
    let items = all
        .into_iter()
        .filter(|b| query.state.is_none_or(|s| b.state == s))
        .map(|b| (b.submitted_at, b.id.clone(), b))
        .collect();
    let (bakes, next) = page(items, cursor.as_ref(), limit);
    let next = next.map(|c| {
        let state = query
            .state
            .map_or(String::new(), |s| format!("&state={}", s.name()));
        format!("/v1/bakes?limit={limit}{state}&cursor={}", c.encode())
    });
    Ok(Json(BakeList { bakes, next }))
}
