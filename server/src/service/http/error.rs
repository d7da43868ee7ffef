//! The one error response of the API: a status and an [`ApiError`] JSON body naming what was
//! wrong (`clutter "pillar2": …`, `settings.rays_per_texel: …`), plus `Retry-After` for 429.
//!
//! Invariant: handlers return `Result<_, ApiFailure>`; nothing else writes error bodies, and an
//! internal failure is logged with its detail while the client gets a short message.

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

    pub fn too_large(message: impl Into<String>) -> ApiFailure {
        ApiFailure::new(StatusCode::PAYLOAD_TOO_LARGE, message)
    }

    pub fn internal(context: &str, detail: impl std::fmt::Display) -> ApiFailure {
        tracing::error!("{context}: {detail}");
        ApiFailure::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("{context}: {detail}"),
        )
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
