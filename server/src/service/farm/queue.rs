//! [`FarmJobs`]: the [`JobQueue`] of a `lightfarm serve --farm` replica. It holds no state of its
//! own: a submission writes the job record to KV and publishes a bake message on the work
//! stream; status reads the record; a subscription forwards the job's core-NATS events; cancel
//! changes the record and announces it on the job's cancel subject, where workers hear it.
//!
//! Invariants:
//! - Submitting a bake that is queued, running or finished (with its bundle still stored) adds
//!   the team to its owners and starts nothing; a failed or cancelled one starts a new attempt.
//! - The queue is bounded like the embedded one: a submission is refused while
//!   `queue_capacity` bake messages wait undelivered on the coordinators' consumer.
//! - A subscriber subscribes to the events subject before it reads the record, and the
//!   forwarding task also re-reads the record every [`RECORD_POLL`], so a final state is never
//!   missed even if its event was (core NATS is at-most-once).
//! - Another team's job is absent (`None`), never forbidden.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use async_nats::HeaderMap;
use futures_util::StreamExt;
use tokio::sync::broadcast;

use lightfarm_proto::api::{BakeEvent, BakeStatus, JobState};

use super::blob_store::FarmStore;
use super::connection::Farm;
use super::job_state::{BakeMessage, FarmJob};
use super::{cancel_subject, events_subject, FarmError, BAKE_SUBJECT, COORDINATOR_CONSUMER};
use crate::service::jobs::{unix_now, BakeRequest, JobQueue, JobRecord, QueueError, QueueMetrics};
use crate::service::store::BlobKind;

/// How often a subscription re-reads the job record besides listening to events.
pub const RECORD_POLL: Duration = Duration::from_secs(2);
/// Retry-After of a refused submission (the farm keeps no bake-time history).
pub const RETRY_AFTER_SECONDS: u64 = 10;

/// The farm's job queue, as a serve replica sees it.
pub struct FarmJobs {
    farm: Arc<Farm>,
    store: Arc<FarmStore>,
    capacity: usize,
}

fn io(e: FarmError) -> QueueError {
    QueueError::Io(e.to_string())
}

impl FarmJobs {
    pub fn new(farm: Arc<Farm>, store: Arc<FarmStore>, capacity: usize) -> FarmJobs {
        FarmJobs {
            farm,
            store,
            capacity,
        }
    }

    /// Bake messages not yet delivered to a coordinator.
    async fn waiting(&self) -> Result<u64, FarmError> {
        let mut consumer = self.farm.consumer(COORDINATOR_CONSUMER).await?;
        let info = consumer
            .info()
            .await
            .map_err(|e| FarmError::nats("coordinators' consumer", e))?;
        Ok(info.num_pending)
    }

    async fn submit_async(&self, request: BakeRequest) -> Result<BakeStatus, QueueError> {
        let farm = &self.farm;
        loop {
            let existing = farm.job(&request.id).await.map_err(io)?;
            if let Some((mut job, revision)) = existing.clone() {
                let reusable = match job.record.state {
                    JobState::Succeeded => match &job.record.bundle {
                        Some(hash) => self.store.exists(BlobKind::Bundle, hash).await,
                        None => false,
                    },
                    JobState::Queued | JobState::Running => true,
                    JobState::Failed | JobState::Cancelled => false,
                };
                if reusable {
                    let finished = job.record.state == JobState::Succeeded;
                    if finished {
                        if let Some(hash) = &job.record.bundle {
                            self.store
                                .allow(&request.team, BlobKind::Bundle, hash)
                                .await
                                .map_err(|e| QueueError::Io(e.to_string()))?;
                        }
                    }
                    if job.record.owners.insert(request.team.clone())
                        && !farm.replace_job(&job, revision).await.map_err(io)?
                    {
                        continue; // changed meanwhile: look again
                    }
                    return Ok(job.record.status(finished));
                }
            }
            if self.waiting().await.map_err(io)? >= self.capacity as u64 {
                return Err(QueueError::Full {
                    capacity: self.capacity,
                    retry_after: RETRY_AFTER_SECONDS,
                });
            }
            let (mut owners, attempt) = match &existing {
                Some((job, _)) => (job.record.owners.clone(), job.attempt + 1),
                None => (Default::default(), 1),
            };
            owners.insert(request.team.clone());
            let job = FarmJob {
                record: JobRecord::queued(&request, owners),
                attempt,
            };
            let written = match &existing {
                Some((_, revision)) => farm.replace_job(&job, *revision).await,
                None => farm.create_job(&job).await,
            }
            .map_err(io)?;
            if !written {
                continue; // another replica wrote it first: answer from its record
            }
            let message = BakeMessage {
                job: job.record.id.clone(),
                attempt,
            };
            let mut headers = HeaderMap::new();
            headers.insert(
                "Nats-Msg-Id",
                format!("bake/{}/{attempt}", job.record.id).as_str(),
            );
            let published = farm
                .jetstream
                .publish_with_headers(
                    BAKE_SUBJECT,
                    headers,
                    serde_json::to_vec(&message).expect("serialises").into(),
                )
                .await;
            let acked = match published {
                Ok(ack) => ack.await.map(|_| ()).map_err(|e| e.to_string()),
                Err(e) => Err(e.to_string()),
            };
            if let Err(e) = acked {
                let message = format!("could not queue the bake on the farm: {e}");
                let _ = farm
                    .update_job(&job.record.id, |j| {
                        j.attempt == attempt && {
                            j.record.state = JobState::Failed;
                            j.record.error = Some(message.clone());
                            true
                        }
                    })
                    .await;
                return Err(QueueError::Io(message));
            }
            farm.publish_event(&job.record.id, &job.record.state_event())
                .await;
            return Ok(job.record.status(false));
        }
    }

    async fn cancel_async(&self, team: &str, id: &str) -> Result<Option<BakeStatus>, FarmError> {
        let Some((job, _)) = self.farm.job(id).await? else {
            return Ok(None);
        };
        if !job.record.owners.contains(team) {
            return Ok(None);
        }
        let mut cancelled_now = false;
        let job = self
            .farm
            .update_job(id, |j| {
                cancelled_now = !j.record.state.is_final();
                if cancelled_now {
                    j.record.state = JobState::Cancelled;
                    j.record.error = Some("cancelled".into());
                    j.record.finished_at = Some(unix_now());
                }
                cancelled_now
            })
            .await?
            .expect("the job was read above");
        if cancelled_now {
            let _ = self
                .farm
                .client
                .publish(cancel_subject(id), job.attempt.to_string().into())
                .await;
            self.farm.publish_event(id, &job.record.state_event()).await;
        }
        Ok(Some(job.record.status(false)))
    }

    async fn subscribe_async(
        &self,
        team: &str,
        id: &str,
    ) -> Result<Option<(BakeStatus, broadcast::Receiver<BakeEvent>)>, FarmError> {
        let mut events = self
            .farm
            .client
            .subscribe(events_subject(id))
            .await
            .map_err(|e| FarmError::nats(format!("subscribe to events of {id}"), e))?;
        // The subscription is registered with the server before the record is read.
        self.farm
            .client
            .flush()
            .await
            .map_err(|e| FarmError::nats("flush", e))?;
        let Some((job, _)) = self.farm.job(id).await? else {
            return Ok(None);
        };
        if !job.record.owners.contains(team) {
            return Ok(None);
        }
        let status = job.record.status(false);
        let (sender, receiver) = broadcast::channel(256);
        if !status.state.is_final() {
            let farm = self.farm.clone();
            let id = id.to_string();
            tokio::spawn(async move {
                let mut poll = tokio::time::interval(RECORD_POLL);
                loop {
                    tokio::select! {
                        message = events.next() => {
                            let Some(message) = message else { return };
                            let Ok(event) = serde_json::from_slice::<BakeEvent>(&message.payload)
                            else {
                                continue;
                            };
                            let last = matches!(&event, BakeEvent::State { state, .. } if state.is_final());
                            if sender.send(event).is_err() || last {
                                return;
                            }
                        }
                        _ = poll.tick() => {
                            if sender.receiver_count() == 0 {
                                return;
                            }
                            if let Ok(Some((job, _))) = farm.job(&id).await {
                                if job.record.state.is_final() {
                                    let _ = sender.send(job.record.state_event());
                                    return;
                                }
                            }
                        }
                    }
                }
            });
        }
        Ok(Some((status, receiver)))
    }

    async fn all_jobs(&self) -> Vec<FarmJob> {
        let mut jobs = Vec::new();
        let Ok(mut keys) = self.farm.jobs.keys().await else {
            return jobs;
        };
        let mut ids = Vec::new();
        while let Some(Ok(key)) = keys.next().await {
            ids.push(key);
        }
        for id in ids {
            if let Ok(Some((job, _))) = self.farm.job(&id).await {
                jobs.push(job);
            }
        }
        jobs
    }
}

impl JobQueue for FarmJobs {
    fn submit(&self, request: BakeRequest) -> Result<BakeStatus, QueueError> {
        self.farm.block_on(self.submit_async(request))
    }

    fn status(&self, team: &str, id: &str) -> Option<BakeStatus> {
        let (job, _) = self.farm.block_on(self.farm.job(id)).ok()??;
        job.record
            .owners
            .contains(team)
            .then(|| job.record.status(false))
    }

    fn list(&self, team: &str) -> Vec<BakeStatus> {
        self.farm
            .block_on(self.all_jobs())
            .into_iter()
            .filter(|job| job.record.owners.contains(team))
            .map(|job| job.record.status(false))
            .collect()
    }

    fn cancel(&self, team: &str, id: &str) -> Option<BakeStatus> {
        match self.farm.block_on(self.cancel_async(team, id)) {
            Ok(status) => status,
            Err(e) => {
                tracing::error!(job = %id, "cancel: {e}");
                None
            }
        }
    }

    fn subscribe(
        &self,
        team: &str,
        id: &str,
    ) -> Option<(BakeStatus, broadcast::Receiver<BakeEvent>)> {
        match self.farm.block_on(self.subscribe_async(team, id)) {
            Ok(found) => found,
            Err(e) => {
                tracing::error!(job = %id, "subscribe: {e}");
                None
            }
        }
    }

    /// The farm does not stream partial bundles: `GET /v1/bakes/{id}/bundle` sends the stored
    /// bundle in one piece once the bake has succeeded.
    fn bundle_prefix(&self, _team: &str, _id: &str) -> Option<Arc<Vec<u8>>> {
        None
    }

    fn shape_uses(&self, team: &str) -> HashMap<String, u64> {
        let mut uses = HashMap::new();
        for job in self.farm.block_on(self.all_jobs()) {
            if job.record.state == JobState::Succeeded && job.record.owners.contains(team) {
                for key in &job.record.shape_keys {
                    *uses.entry(key.clone()).or_insert(0) += 1;
                }
            }
        }
        uses
    }

    fn metrics(&self) -> QueueMetrics {
        let jobs = self.farm.block_on(self.all_jobs());
        let by_state = JobState::ALL
            .iter()
            .map(|s| {
                (
                    *s,
                    jobs.iter().filter(|j| j.record.state == *s).count() as u64,
                )
            })
            .collect();
        QueueMetrics {
            depth: self.farm.block_on(self.waiting()).unwrap_or(0),
            by_state,
            ..QueueMetrics::default()
        }
    }

    fn shutdown(&self) {}
}
