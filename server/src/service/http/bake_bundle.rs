//! `GET /v1/bakes/{id}/bundle`: a bake's bundle as it is being written. The response starts with
//! the sections that are final (layout, shapes, blocks and MRT transport first; then DRT,
//! probes, DNRT), keeps streaming as more finish, and ends with the rest of the stored bundle,
//! so a client can decode the MRT part (`Bundle::decode_prefix`) before DRT and DNRT arrive and
//! ends up with exactly the bytes of `GET /v1/bundles/{hash}`.
//!
//! Invariants: every byte sent is a byte of the final bundle at the same offset: the stored
//! bundle is checked to begin with what was sent before the rest goes out, and a mismatch, a
//! failed or a cancelled bake aborts the response (the client sees a truncated body, never a
//! wrong one). A finished bake is answered from the store in one piece.

use std::sync::Arc;

use axum::body::Body;
use axum::extract::{Path, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use bytes::Bytes;
use futures_util::stream;
use tokio::sync::broadcast::error::RecvError;

use lightfarm_proto::api::{ApiError, JobState};

use super::auth::Caller;
use super::bundles::SharedBlob;
use super::error::{blocking, ApiFailure};
use super::AppState;
use crate::service::store::BlobKind;

struct Streaming {
    state: AppState,
    team: String,
    id: String,
    /// The bytes sent so far are `sent[..]` of this prefix.
    sent: Option<Arc<Vec<u8>>>,
    receiver: tokio::sync::broadcast::Receiver<lightfarm_proto::api::BakeEvent>,
    done: bool,
}

fn sent_len(s: &Streaming) -> usize {
    s.sent.as_ref().map_or(0, |p| p.len())
}

/// Whether `prefix` holds more than `sent` and starts with it.
fn extends(prefix: &[u8], sent: &[u8]) -> bool {
    prefix.len() > sent.len() && prefix[..sent.len()] == *sent
}

async fn next_chunk(mut s: Streaming) -> Option<(Result<Bytes, std::io::Error>, Streaming)> {
    loop {
        if s.done {
            return None;
        }
        // Off the runtime (the queue's lock is held while a job record is written to disk): the
        // prefix, if it extends what was sent (compared there too), else the job's status.
        let (jobs, team, id) = (s.state.jobs.clone(), s.team.clone(), s.id.clone());
        let sent = s.sent.clone();
        let next = tokio::task::spawn_blocking(move || match jobs.bundle_prefix(&team, &id) {
            Some(prefix) if extends(&prefix, sent.as_deref().map_or(&[], |v| &v[..])) => Ok(prefix),
            _ => Err(jobs.status(&team, &id).map(Box::new)),
        })
        .await
        .ok()?;
        let status = match next {
            Ok(prefix) => {
                let chunk = Bytes::from_owner(SharedBlob(prefix.clone())).slice(sent_len(&s)..);
                s.sent = Some(prefix);
                return Some((Ok(chunk), s));
            }
            Err(status) => *status?,
        };
        match status.state {
            JobState::Succeeded => {
                s.done = true;
                let store = s.state.store.clone();
                let hash = status.bundle.clone().unwrap_or_default();
                let stored =
                    tokio::task::spawn_blocking(move || store.get(BlobKind::Bundle, &hash))
                        .await
                        .ok()
                        .and_then(|r| r.ok())
                        .flatten();
                let Some(bundle) = stored else {
                    return Some((
                        Err(std::io::Error::other("bundle missing from the store")),
                        s,
                    ));
                };
                let from = sent_len(&s);
                let consistent = s
                    .sent
                    .as_ref()
                    .is_none_or(|p| bundle.len() >= p.len() && bundle[..p.len()] == p[..]);
                if !consistent {
                    tracing::error!(job = %s.id, "streamed prefix differs from the stored bundle");
                    return Some((Err(std::io::Error::other("streamed prefix differs")), s));
                }
                let chunk = Bytes::from_owner(SharedBlob(bundle)).slice(from..);
                return Some((Ok(chunk), s));
            }
            JobState::Failed | JobState::Cancelled => {
                s.done = true;
                let why = format!("bake {}", status.state.name());
                return Some((Err(std::io::Error::other(why)), s));
            }
            JobState::Queued | JobState::Running => match s.receiver.recv().await {
                Ok(_) | Err(RecvError::Lagged(_)) => continue,
                Err(RecvError::Closed) => return None,
            },
        }
    }
}

/// Stream a bake's bundle while it is written.
#[utoipa::path(
    get,
    path = "/v1/bakes/{id}/bundle",
    tag = "bakes",
    params(("id" = String, Path, description = "Bake id")),
    responses(
        (status = 200, description = "The bundle's bytes, streamed as its sections finish", content_type = "application/vnd.lightfarm.bundle"),
        (status = 404, description = "No such bake for this team", body = ApiError),
        (status = 409, description = "The bake failed or was cancelled", body = ApiError),
    ),
    security(("bearer" = []))
)]
pub async fn stream_bake_bundle(
    State(state): State<AppState>,
    Caller(team): Caller,
    Path(id): Path<String>,
) -> Result<Response, ApiFailure> {
    // Subscribe before looking, so nothing that happens in between is missed.
    let (jobs, subscriber, key) = (state.jobs.clone(), team.clone(), id.clone());
    let (status, receiver) = blocking(move || Ok(jobs.subscribe(&subscriber, &key)))
        .await?
        .ok_or_else(|| ApiFailure::not_found("bake", &id))?;
    if matches!(status.state, JobState::Failed | JobState::Cancelled) {
        return Err(ApiFailure::new(
            StatusCode::CONFLICT,
            format!(
                "bake {id} {}: {}",
                status.state.name(),
                status.error.unwrap_or_default()
            ),
        ));
    }
    let streaming = Streaming {
        state,
        team,
        id,
        sent: None,
        receiver,
        done: false,
    };
    let body = Body::from_stream(stream::unfold(streaming, next_chunk));
    let mut response = (StatusCode::OK, body).into_response();
    response.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/vnd.lightfarm.bundle"),
    );
    Ok(response)
}
