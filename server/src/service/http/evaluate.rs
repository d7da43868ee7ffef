//! `POST /v1/bakes/{id}/evaluate?method=drt|mrt&bounces=N|all`: a finished bake's bundle
//! applied to a LIGHTS.json document, answered with the RESULT.json document
//! `lightfarm eval BUNDLE --lights L --method M --bounces N -o R.json` writes for the same bundle
//! and lights (per texel: surface, index, position, normal, albedo, direct and indirect radiance
//! in W/(sr·m²)). Editors use it to show baked light, and to relight after a light moved,
//! without a rebake and without shipping the client library. `bounces` defaults to `all` (as
//! `eval` does); the headers `lightfarm-bounces` and `lightfarm-remaining-fraction` say how many
//! bounces the runtime summed and what it estimates the rest to add (as `eval` prints). The
//! document is compressed (gzip or zstd) when the request's `Accept-Encoding` asks for it.
//!
//! Invariants: the evaluation is [`crate::evaluate::evaluate_with_report`], called from this one
//! place, on a blocking thread; this file does no light transport of its own. Another team's bake, an
//! unknown one and one that has not succeeded are 404; lights that do not parse or validate are
//! 422 with the message naming the field (`lights[0]: intensity …`, `poses[1].id: …`).

use axum::body::Bytes;
use axum::extract::rejection::{BytesRejection, QueryRejection};
use axum::extract::{Path, Query, State};
use axum::http::HeaderValue;
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Deserialize;

use lightfarm_client::{Bundle, Method};
use lightfarm_proto::api::{ApiError, JobState};
use lightfarm_proto::bounces::{BounceCount, BounceCountError};
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::ResultFile;

use super::auth::Caller;
use super::error::{blocking, body_failure, ApiFailure};
use super::AppState;
use crate::service::store::BlobKind;

/// Which operators to apply (as `lightfarm eval --method`; `full` needs a dense operator the
/// service never bakes, so it is not offered).
#[derive(Clone, Copy, Debug, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum EvaluateMethod {
    /// Modular Radiance Transfer plus the clutter operators (DRT); MRT where the bundle has no
    /// clutter operators. The default.
    Drt,
    /// Blocks only; clutter shaded from the probe volume.
    Mrt,
}

/// Query of `POST /v1/bakes/{id}/evaluate`. Read as text and parsed here, so that a 422 names
/// the parameter that is wrong.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct EvaluateQuery {
    /// `drt` (default) or `mrt`.
    #[param(value_type = Option<EvaluateMethod>, inline)]
    pub method: Option<String>,
    /// Bounces of indirect light: a whole number ≥ 1 (`1` or `one` is the papers' one-bounce
    /// light) or `all` (the default: summed until the rest is estimated below 0.1% of the light).
    #[param(value_type = Option<String>, pattern = "^([1-9][0-9]*|one|all)$", example = "all")]
    pub bounces: Option<String>,
}

/// Response header: the runtime's applications of the one-bounce operator (the bounces summed;
/// for all bounces, the first plus the GMRES iterations).
pub const BOUNCES_HEADER: &str = "lightfarm-bounces";
/// Response header: for all bounces, the runtime's estimate of its error relative to all
/// bounces (`Applied::remaining_fraction`); 0 for a fixed number of bounces.
pub const REMAINING_HEADER: &str = "lightfarm-remaining-fraction";

/// Apply a finished bake's bundle to a set of lights.
#[utoipa::path(
    post,
    path = "/v1/bakes/{id}/evaluate",
    tag = "bakes",
    params(("id" = String, Path, description = "Bake id"), EvaluateQuery),
    request_body(content = LightSet, description = "LIGHTS.json: point lights (W/sr) and poses of dynamic objects"),
    responses(
        (status = 200, description = "RESULT.json: per-texel direct and indirect radiance, as `lightfarm eval` writes it", body = ResultFile,
            headers(
                ("lightfarm-bounces" = u32, description = "Applications of the one-bounce operator (bounces summed; for all bounces the first plus the solver's iterations)"),
                ("lightfarm-remaining-fraction" = f32, description = "For all bounces: the estimated error relative to all bounces; 0 for a fixed number"),
            )),
        (status = 401, description = "No or unknown token", body = ApiError),
        (status = 404, description = "No such bake for this team, or it has not succeeded", body = ApiError),
        (status = 413, description = "Body larger than limits.max_body_bytes", body = ApiError),
        (status = 422, description = "Invalid lights, method or bounces; the message names the field", body = ApiError),
        (status = 500, description = "The stored bundle could not be read or applied", body = ApiError),
    ),
    security(("bearer" = []))
)]
pub async fn evaluate_bake(
    State(state): State<AppState>,
    Caller(team): Caller,
    Path(id): Path<String>,
    query: Result<Query<EvaluateQuery>, QueryRejection>,
    body: Result<Bytes, BytesRejection>,
) -> Result<Response, ApiFailure> {
    let Query(query) = query.map_err(|r| ApiFailure::unprocessable(r.body_text()))?;
    let method = match query.method.as_deref() {
        None | Some("drt") => Method::Drt,
        Some("mrt") => Method::Mrt,
        Some(other) => {
            return Err(ApiFailure::unprocessable(format!(
                "method: expected \"drt\" or \"mrt\", got \"{other}\""
            )))
        }
    };
    let bounces: BounceCount = match query.bounces.as_deref() {
        None => BounceCount::default(),
        Some(text) => text
            .parse()
            .map_err(|e: BounceCountError| ApiFailure::unprocessable(e.to_string()))?,
    };
    let bounces = bounces.into();
    let body = body.map_err(|r| body_failure(r, state.config.limits.max_body_bytes))?;
    let text = std::str::from_utf8(&body)
        .map_err(|_| ApiFailure::unprocessable("lights: the body is not UTF-8 JSON"))?;
    let lights = LightSet::from_json(text).map_err(|e| ApiFailure::unprocessable(e.to_string()))?;
    let status = state
        .jobs
        .status(&team, &id)
        .ok_or_else(|| ApiFailure::not_found("bake", &id))?;
    let hash = match (status.state, status.bundle) {
        (JobState::Succeeded, Some(hash)) => hash,
        (state, _) => {
            return Err(ApiFailure::not_found(
                "bake",
                &format!("{id} (no bundle: the bake is {})", state.name()),
            ))
        }
    };
    let store = state.store.clone();
    let (result, applied) = blocking(move || {
        let bytes = store
            .get(BlobKind::Bundle, &hash)
            .map_err(|e| ApiFailure::internal("store", e))?
            .ok_or_else(|| {
                ApiFailure::not_found("bundle", &format!("{hash} (no longer stored)"))
            })?;
        let bundle = Bundle::decode(&bytes).map_err(|e| ApiFailure::internal("bundle", e))?;
        let grids = bundle.dnrt.as_deref().unwrap_or(&[]);
        for (k, pose) in lights.poses.iter().enumerate() {
            if !grids.iter().any(|g| g.object == pose.id) {
                return Err(ApiFailure::unprocessable(format!(
                    "poses[{k}].id: \"{}\" is no dynamic object of this bake",
                    pose.id
                )));
            }
        }
        crate::evaluate::evaluate_with_report(bundle, &lights, method, bounces)
            .map_err(|e| ApiFailure::internal("evaluate", format!("{e:#}")))
    })
    .await?;
    let mut response = Json(result).into_response();
    let headers = response.headers_mut();
    headers.insert(BOUNCES_HEADER, HeaderValue::from(applied.bounces));
    if let Ok(value) = HeaderValue::from_str(&format!("{:.3e}", applied.remaining_fraction)) {
        headers.insert(REMAINING_HEADER, value);
    }
    Ok(response)
}
