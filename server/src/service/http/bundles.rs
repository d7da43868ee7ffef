//! `GET /v1/bundles/{hash}`: a finished bundle, immutable and named by its content hash.
//!
//! Invariants:
//! - The strong `ETag` is the hash (`"<hash>"`; the zstd-encoded representation is
//!   `"<hash>.zst"`); `If-None-Match` with either → 304 without a body.
//! - `Range: bytes=…` (one range) → 206 with `Content-Range`, always of the identity bytes;
//!   an unsatisfiable range → 416. `If-Range` with another validator → the whole body (200).
//! - `Accept-Encoding: zstd` (and no range) → the bytes zstd-compressed, `Vary: Accept-Encoding`,
//!   when that is smaller. Bundle sections are already zstd-compressed, so it rarely is (the
//!   cornell bundle grows by 79 bytes) and the identity form is sent instead; the identity form
//!   is also what the client's fetcher asks for.
//! - Bytes are verified against the hash on every read (by the store); a corrupt bundle is never
//!   sent: it is dropped and reported absent, and baking the same scene again rebuilds it.
//! - The store is read off the async runtime (`blocking`): the team's grant and the blob's
//!   presence are files too, and a slow disk must hold a blocking thread, not a runtime worker.

use axum::body::Body;
use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};

use lightfarm_proto::api::ApiError;

use super::auth::Caller;
use super::error::{blocking, ApiFailure};
use super::AppState;
use crate::service::store::BlobKind;

/// A stored blob as a response body without copying it.
pub(super) struct SharedBlob(pub(super) std::sync::Arc<Vec<u8>>);

impl AsRef<[u8]> for SharedBlob {
    fn as_ref(&self) -> &[u8] {
        self.0.as_slice()
    }
}

/// What the store holds for a request: invisible to the team, unchanged since the client's
/// copy, gone, or the bytes.
enum Lookup {
    Hidden,
    NotModified,
    Gone,
    Bytes(std::sync::Arc<Vec<u8>>),
}

/// zstd level for the encoded representation.
const TRANSFER_ZSTD_LEVEL: i32 = 3;

/// What a `Range` header asks of a body of `len` bytes.
#[derive(Debug, PartialEq, Eq)]
pub enum RangeRequest {
    Whole,
    /// Inclusive byte range.
    Part(u64, u64),
    Unsatisfiable,
}

/// Parses a single `bytes=` range (`a-b`, `a-`, `-n`); several ranges or other units are
/// answered with the whole body, as RFC 9110 allows.
pub fn parse_range(value: &str, len: u64) -> RangeRequest {
    let Some(spec) = value.trim().strip_prefix("bytes=") else {
        return RangeRequest::Whole;
    };
    if spec.contains(',') {
        return RangeRequest::Whole;
    }
    let Some((a, b)) = spec.trim().split_once('-') else {
        return RangeRequest::Whole;
    };
    let (a, b) = (a.trim(), b.trim());
    let parsed = match (a.is_empty(), b.is_empty()) {
        (true, true) => return RangeRequest::Whole,
        (true, false) => match b.parse::<u64>() {
            Ok(0) => return RangeRequest::Unsatisfiable,
            Ok(n) => Some((len.saturating_sub(n), len.wrapping_sub(1))),
            Err(_) => return RangeRequest::Whole,
        },
        (false, _) => {
            let Ok(start) = a.parse::<u64>() else {
                return RangeRequest::Whole;
            };
            let end = if b.is_empty() {
                len.wrapping_sub(1)
            } else {
                match b.parse::<u64>() {
                    Ok(e) if e >= start => e.min(len.wrapping_sub(1)),
                    _ => return RangeRequest::Whole,
                }
            };
            Some((start, end))
        }
    };
    match parsed {
        Some((start, end)) if len > 0 && start < len && start <= end => {
            RangeRequest::Part(start, end)
        }
        _ => RangeRequest::Unsatisfiable,
    }
}

fn etag_matches(if_none_match: &str, hash: &str) -> bool {
    if_none_match.trim() == "*"
        || if_none_match.split(',').any(|tag| {
            let tag = tag.trim().trim_start_matches("W/").trim_matches('"');
            tag == hash || tag.strip_suffix(".zst") == Some(hash)
        })
}

fn accepts_zstd(headers: &HeaderMap) -> bool {
    headers
        .get_all(header::ACCEPT_ENCODING)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|coding| {
            let mut parts = coding.split(';');
            let name = parts.next().unwrap_or("").trim();
            let q_zero = parts.any(|p| p.trim().replace(' ', "") == "q=0");
            name.eq_ignore_ascii_case("zstd") && !q_zero
        })
}

/// Download a bundle.
#[utoipa::path(
    get,
    path = "/v1/bundles/{hash}",
    tag = "bundles",
    params(("hash" = String, Path, description = "Bundle content hash")),
    responses(
        (status = 200, description = "The bundle", content_type = "application/vnd.lightfarm.bundle"),
        (status = 206, description = "The requested byte range"),
        (status = 304, description = "Not modified (If-None-Match)"),
        (status = 404, description = "No such bundle for this team", body = ApiError),
        (status = 416, description = "Range not satisfiable", body = ApiError),
    ),
    security(("bearer" = []))
)]
pub async fn get_bundle(
    State(state): State<AppState>,
    Caller(team): Caller,
    Path(hash): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiFailure> {
    let etag = format!("\"{hash}\"");
    let mut out = HeaderMap::new();
    out.insert(header::ETAG, HeaderValue::from_str(&etag).expect("hex"));
    out.insert(
        header::CACHE_CONTROL,
        HeaderValue::from_static("private, max-age=31536000, immutable"),
    );
    out.insert(header::ACCEPT_RANGES, HeaderValue::from_static("bytes"));
    out.insert(header::VARY, HeaderValue::from_static("Accept-Encoding"));
    let if_none_match = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .map(str::to_owned);
    // Every look at the store (the team's grant, the blob's presence, its bytes) is file work,
    // kept off the async runtime.
    let store = state.store.clone();
    let key = hash.clone();
    let lookup = blocking(move || {
        if !store.visible(&team, BlobKind::Bundle, &key) {
            return Ok(Lookup::Hidden);
        }
        if if_none_match.is_some_and(|inm| etag_matches(&inm, &key))
            && store.contains(BlobKind::Bundle, &key)
        {
            return Ok(Lookup::NotModified);
        }
        store
            .get(BlobKind::Bundle, &key)
            .map(|bytes| bytes.map_or(Lookup::Gone, Lookup::Bytes))
            .map_err(|e| ApiFailure::internal("store", e))
    })
    .await?;
    let bytes = match lookup {
        Lookup::Hidden => return Err(ApiFailure::not_found("bundle", &hash)),
        Lookup::NotModified => return Ok((StatusCode::NOT_MODIFIED, out).into_response()),
        Lookup::Gone => {
            return Err(ApiFailure::not_found(
                "bundle",
                &format!(
                    "{hash} (no longer stored, or found corrupt and dropped; bake the scene again)"
                ),
            ))
        }
        Lookup::Bytes(bytes) => bytes,
    };
    out.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/vnd.lightfarm.bundle"),
    );
    let len = bytes.len() as u64;
    let range_applies = match headers.get(header::IF_RANGE).and_then(|v| v.to_str().ok()) {
        Some(validator) => validator.trim() == etag,
        None => true,
    };
    let range = headers
        .get(header::RANGE)
        .and_then(|v| v.to_str().ok())
        .filter(|_| range_applies)
        .map(|v| parse_range(v, len))
        .unwrap_or(RangeRequest::Whole);
    match range {
        RangeRequest::Part(start, end) => {
            out.insert(
                header::CONTENT_RANGE,
                HeaderValue::from_str(&format!("bytes {start}-{end}/{len}")).expect("ascii"),
            );
            let part =
                bytes::Bytes::from_owner(SharedBlob(bytes)).slice(start as usize..=end as usize);
            Ok((StatusCode::PARTIAL_CONTENT, out, Body::from(part)).into_response())
        }
        RangeRequest::Unsatisfiable => {
            out.insert(
                header::CONTENT_RANGE,
                HeaderValue::from_str(&format!("bytes */{len}")).expect("ascii"),
            );
            let mut response = ApiFailure::new(
                StatusCode::RANGE_NOT_SATISFIABLE,
                format!("range not satisfiable: the bundle has {len} bytes"),
            )
            .into_response();
            response.headers_mut().extend(out);
            Ok(response)
        }
        RangeRequest::Whole if accepts_zstd(&headers) => {
            let (bytes, encoded) = blocking(move || {
                let encoded = zstd::bulk::compress(&bytes, TRANSFER_ZSTD_LEVEL)
                    .map_err(|e| ApiFailure::internal("zstd", e))?;
                Ok((bytes, encoded))
            })
            .await?;
            if encoded.len() >= bytes.len() {
                let body = Body::from(bytes::Bytes::from_owner(SharedBlob(bytes)));
                return Ok((StatusCode::OK, out, body).into_response());
            }
            out.insert(
                header::ETAG,
                HeaderValue::from_str(&format!("\"{hash}.zst\"")).expect("hex"),
            );
            out.insert(header::CONTENT_ENCODING, HeaderValue::from_static("zstd"));
            Ok((StatusCode::OK, out, Body::from(encoded)).into_response())
        }
        RangeRequest::Whole => {
            let body = Body::from(bytes::Bytes::from_owner(SharedBlob(bytes)));
            Ok((StatusCode::OK, out, body).into_response())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges() {
        use RangeRequest::*;
        assert_eq!(parse_range("bytes=0-9", 100), Part(0, 9));
        assert_eq!(parse_range("bytes=90-", 100), Part(90, 99));
        assert_eq!(parse_range("bytes=-10", 100), Part(90, 99));
        assert_eq!(parse_range("bytes=-1000", 100), Part(0, 99));
        assert_eq!(parse_range("bytes=50-1000", 100), Part(50, 99));
        assert_eq!(parse_range("bytes=100-", 100), Unsatisfiable);
        assert_eq!(parse_range("bytes=-0", 100), Unsatisfiable);
        assert_eq!(parse_range("bytes=0-", 0), Unsatisfiable);
        assert_eq!(parse_range("bytes=5-2", 100), Whole);
        assert_eq!(parse_range("bytes=0-1,5-6", 100), Whole);
        assert_eq!(parse_range("items=0-1", 100), Whole);
        assert_eq!(parse_range("bytes=x-1", 100), Whole);
    }

    #[test]
    fn etags_and_encodings() {
        let h = "ab".repeat(32);
        assert!(etag_matches(&format!("\"{h}\""), &h));
        assert!(etag_matches(&format!("\"x\", \"{h}.zst\""), &h));
        assert!(etag_matches("*", &h));
        assert!(!etag_matches("\"other\"", &h));
        let mut headers = HeaderMap::new();
        headers.insert(
            header::ACCEPT_ENCODING,
            HeaderValue::from_static("gzip, zstd;q=0.8"),
        );
        assert!(accepts_zstd(&headers));
        headers.insert(
            header::ACCEPT_ENCODING,
            HeaderValue::from_static("zstd;q=0, gzip"),
        );
        assert!(!accepts_zstd(&headers));
    }
}
