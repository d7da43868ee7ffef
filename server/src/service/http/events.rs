//! `GET /v1/bakes/{id}/events`: server-sent events for every stage change, progress step
//! (throttled by the job's progress hook) and state change of a bake.
//!
//! Invariants: the stream opens with the current state (so a late subscriber knows where the
//! bake is), ends after a final state, and ends when the server shuts down (so graceful shutdown
//! is not held open by watchers). A subscriber too slow to keep up skips events, never blocks the
//! bake.

use std::convert::Infallible;
use std::time::Duration;

use axum::extract::{Path, State};
use axum::response::sse::{Event, KeepAlive, Sse};
use futures_util::stream::{self, Stream, StreamExt};
use tokio::sync::broadcast::error::RecvError;

use lightfarm_proto::api::{ApiError, BakeEvent};

use super::auth::Caller;
use super::error::{blocking, ApiFailure};
use super::AppState;

fn to_sse(event: &BakeEvent) -> Event {
    Event::default()
        .event(event.kind())
        .data(serde_json::to_string(event).expect("events serialise"))
}

/// Stream a bake's events.
#[utoipa::path(
    get,
    path = "/v1/bakes/{id}/events",
    tag = "bakes",
    params(("id" = String, Path, description = "Bake id")),
    responses(
        (status = 200, description = "text/event-stream of BakeEvent (event name = kind)", body = BakeEvent, content_type = "text/event-stream"),
        (status = 404, description = "No such bake for this team", body = ApiError),
    ),
    security(("bearer" = []))
)]
pub async fn bake_events(
    State(state): State<AppState>,
    Caller(team): Caller,
    Path(id): Path<String>,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiFailure> {
    let jobs = state.jobs.clone();
    let key = id.clone();
    let (status, receiver) = blocking(move || Ok(jobs.subscribe(&team, &key)))
        .await?
        .ok_or_else(|| ApiFailure::not_found("bake", &id))?;
    let first = BakeEvent::State {
        state: status.state,
        error: status.error.clone(),
        bundle: status.bundle.clone(),
    };
    let already_final = status.state.is_final();
    let mut stage_now = Vec::new();
    if let (Some(stage), false) = (&status.stage, already_final) {
        stage_now.push(BakeEvent::Stage {
            stage: stage.clone(),
            total: status.stage_total,
        });
        stage_now.push(BakeEvent::Progress {
            stage: stage.clone(),
            done: status.stage_done,
            total: status.stage_total,
            overall: status.progress,
        });
    }
    let opening = stream::iter(
        std::iter::once(first)
            .chain(stage_now)
            .map(|e| Ok(to_sse(&e)))
            .collect::<Vec<_>>(),
    );
    // (receiver, finished)
    let live = stream::unfold(
        (receiver, already_final),
        |(mut receiver, finished)| async move {
            if finished {
                return None;
            }
            loop {
                match receiver.recv().await {
                    Ok(event) => {
                        let done =
                            matches!(&event, BakeEvent::State { state, .. } if state.is_final());
                        return Some((Ok(to_sse(&event)), (receiver, done)));
                    }
                    Err(RecvError::Lagged(_)) => continue,
                    Err(RecvError::Closed) => return None,
                }
            }
        },
    );
    let mut shutdown = state.shutdown.clone();
    let stream = opening.chain(live).take_until(async move {
        let _ = shutdown.wait_for(|stopping| *stopping).await;
    });
    Ok(Sse::new(stream).keep_alive(KeepAlive::new().interval(Duration::from_secs(15))))
}
