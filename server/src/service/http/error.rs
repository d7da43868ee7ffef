//! The one error response of the API: a status and an [`ApiError`] JSON body naming what was
//! wrong (`clutter "pillar2": …`, `settings.rays_per_texel: …`), plus `Retry-After` for 429.
//!
//! Invariant: handlers return `Result<_, ApiFailure>`; nothing else writes error bodies. An
//! internal failure is logged with its detail and the request id; the client gets
//! `internal error (request <id>)` and nothing more ([`hide_internal_detail`] writes that body
//! for every 500, whoever produced it).

use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;

use lightfarm_proto::api::ApiError;

/// An error response.
#[derive(Debug)]
pub struct ApiFailure {
    pub status: StatusCode,
    pub message: String,
    pub retry_after: Option<u64>,
}

impl ApiFailure {
    pub fn new(status: StatusCode, message: impl Into<String>) -> ApiFailure {
        ApiFailure {
            status,
            message: message.into(),
            retry_after: None,
        }
    }

    pub fn not_found(what: &str, id: &str) -> ApiFailure {
        ApiFailure::new(StatusCode::NOT_FOUND, format!("{what} {id} not found"))
    }

    pub fn unprocessable(message: impl Into<String>) -> ApiFailure {
        ApiFailure::new(StatusCode::UNPROCESSABLE_ENTITY, message)
    }

    /// A 400 for a query string the handler's query type does not accept (axum's message
    /// names the parameter).
    pub fn bad_query(rejection: axum::extract::rejection::QueryRejection) -> ApiFailure {
        ApiFailure::new(StatusCode::BAD_REQUEST, rejection.body_text())
    }

    pub fn too_large(message: impl Into<String>) -> ApiFailure {
        ApiFailure::new(StatusCode::PAYLOAD_TOO_LARGE, message)
    }

    /// A 500: `context` and `detail` go to the log (inside the request's span, with its id),
    /// never to the client.
    pub fn internal(context: &str, detail: impl std::fmt::Display) -> ApiFailure {
        tracing::error!("{context}: {detail}");
        ApiFailure::new(StatusCode::INTERNAL_SERVER_ERROR, "internal error")
    }
}

impl IntoResponse for ApiFailure {
    fn into_response(self) -> Response {
        let mut response = (
            self.status,
            Json(ApiError {
                error: self.message,
            }),
        )
            .into_response();
        if let Some(seconds) = self.retry_after {
            response
                .headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from(seconds));
        }
        response
    }
}

/// A request body that could not be read: over the size limit (413) or broken (400).
pub fn body_failure(
    rejection: axum::extract::rejection::BytesRejection,
    limit: usize,
) -> ApiFailure {
    if rejection.status() == StatusCode::PAYLOAD_TOO_LARGE {
        ApiFailure::too_large(format!(
            "request body is larger than limits.max_body_bytes = {limit} bytes"
        ))
    } else {
        ApiFailure::new(rejection.status(), rejection.body_text())
    }
}

/// Runs CPU or file work off the async runtime.
pub async fn blocking<T: Send + 'static>(
    work: impl FnOnce() -> Result<T, ApiFailure> + Send + 'static,
) -> Result<T, ApiFailure> {
    tokio::task::spawn_blocking(work)
        .await
        .map_err(|e| ApiFailure::internal("worker task", e))?
}

/// Middleware: every 500 leaves with the body `internal error (request <id>)` (the id of the
/// `x-request-id` header), whatever wrote it, so no internal detail reaches a client.
pub async fn hide_internal_detail(
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let id = request
        .headers()
        .get("x-request-id")
        .and_then(|v| v.to_str().ok())
        .unwrap_or("-")
        .to_string();
    let response = next.run(request).await;
    if response.status() != StatusCode::INTERNAL_SERVER_ERROR {
        return response;
    }
    let mut hidden = ApiFailure::new(
        StatusCode::INTERNAL_SERVER_ERROR,
        format!("internal error (request {id})"),
    )
    .into_response();
    for (name, value) in response.headers() {
        if name != header::CONTENT_TYPE && name != header::CONTENT_LENGTH {
            hidden.headers_mut().insert(name.clone(), value.clone());
        }
    }
    hidden
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::body::Body;
    use axum::routing::get;
    use axum::Router;
    use tower::ServiceExt;

    /// A handler's internal failure and a bare 500 both leave as `internal error (request id)`;
    /// other errors keep their message.
    #[tokio::test]
    async fn a_500_body_names_the_request_not_the_detail() {
        let app = Router::new()
            .route(
                "/store",
                get(|| async { ApiFailure::internal("store", "/var/lib/lightfarm/blobs: EIO") }),
            )
            .route(
                "/bare",
                get(|| async { (StatusCode::INTERNAL_SERVER_ERROR, "panic at foo.rs:3") }),
            )
            .route(
                "/missing",
                get(|| async { ApiFailure::not_found("bake", "abc") }),
            )
            .layer(axum::middleware::from_fn(hide_internal_detail));
        for (path, status, body) in [
            (
                "/store",
                500,
                "{\"error\":\"internal error (request r-7)\"}",
            ),
            ("/bare", 500, "{\"error\":\"internal error (request r-7)\"}"),
            ("/missing", 404, "{\"error\":\"bake abc not found\"}"),
        ] {
            let request = axum::http::Request::get(path)
                .header("x-request-id", "r-7")
                .body(Body::empty())
                .unwrap();
            let response = app.clone().oneshot(request).await.unwrap();
            assert_eq!(response.status().as_u16(), status, "{path}");
            let bytes = axum::body::to_bytes(response.into_body(), 1 << 16)
                .await
                .unwrap();
            assert_eq!(std::str::from_utf8(&bytes).unwrap(), body, "{path}");
        }
    }
}
