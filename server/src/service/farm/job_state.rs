//! Job and unit records in the farm's KV buckets, the messages on the work stream, and a job's
//! events on core NATS.
//!
//! A job record ([`FarmJob`]) is the embedded service's [`JobRecord`] plus the attempt number:
//! a failed or cancelled bake submitted again is a new attempt of the same job id, and every
//! message carries the attempt it belongs to, so work left over from an earlier attempt
//! recognises itself and stops. A unit's completion ([`UnitDone`]) is keyed by job and unit, not
//! attempt: units are deterministic, so an earlier attempt's finished unit is as good as new.
//!
//! Invariants:
//! - Records change only by compare-and-set on the KV revision ([`Farm::update_job`]), so a
//!   cancel on one replica and a worker's progress never overwrite each other, and a final state
//!   is never left again by a late writer of the same attempt.
//! - A job's state event is published after the record that holds it is written, so a watcher
//!   that reads the record after subscribing misses nothing.

use async_nats::jetstream::kv;
use serde::{Deserialize, Serialize};

use lightfarm_proto::api::BakeEvent;

use super::connection::Farm;
use super::{events_subject, key_token, FarmError};
use crate::service::jobs::JobRecord;

/// A job as stored in `lightfarm_jobs`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FarmJob {
    #[serde(flatten)]
    pub record: JobRecord,
    /// 1 for the first submission, one more for each resubmission after a failure or cancel.
    pub attempt: u64,
}

/// A bake message: coordinate this attempt of this job.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BakeMessage {
    pub job: String,
    pub attempt: u64,
}

/// A unit message: run this unit of this attempt of this job.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct UnitMessage {
    pub job: String,
    pub attempt: u64,
    /// [`crate::bake::units::BakeUnit::name`].
    pub unit: String,
}

/// A finished unit, as stored in `lightfarm_units`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct UnitDone {
    /// Cache files (relative paths) the unit wrote, uploaded to the operators object store.
    pub outputs: Vec<String>,
    /// Set when the unit failed (the job fails with this message).
    pub error: Option<String>,
    pub worker: String,
    pub seconds: f64,
}

fn unit_key(job: &str, unit: &str) -> String {
    format!("{job}.{}", key_token(unit))
}

impl Farm {
    /// The job record and its KV revision.
    pub async fn job(&self, id: &str) -> Result<Option<(FarmJob, u64)>, FarmError> {
        if !crate::service::store::is_hash(id) {
            return Ok(None);
        }
        let entry = self
            .jobs
            .entry(id)
            .await
            .map_err(|e| FarmError::nats(format!("read job {id}"), e))?;
        let Some(entry) = entry else {
            return Ok(None);
        };
        if entry.operation != kv::Operation::Put {
            return Ok(None);
        }
        let job = serde_json::from_slice(&entry.value)
            .map_err(|e| FarmError::nats(format!("job record {id}"), e))?;
        Ok(Some((job, entry.revision)))
    }

    /// Writes a new job record unless one exists; `false` when one does.
    pub async fn create_job(&self, job: &FarmJob) -> Result<bool, FarmError> {
        let bytes = serde_json::to_vec(job).expect("records serialise");
        match self.jobs.create(&job.record.id, bytes.into()).await {
            Ok(_) => Ok(true),
            Err(e) if e.kind() == kv::CreateErrorKind::AlreadyExists => Ok(false),
            Err(e) => Err(FarmError::nats(format!("create job {}", job.record.id), e)),
        }
    }

    /// Replaces the record at `revision`; `false` when someone changed it in between.
    pub async fn replace_job(&self, job: &FarmJob, revision: u64) -> Result<bool, FarmError> {
        let bytes = serde_json::to_vec(job).expect("records serialise");
        match self
            .jobs
            .update(&job.record.id, bytes.into(), revision)
            .await
        {
            Ok(_) => Ok(true),
            Err(e) if e.kind() == kv::UpdateErrorKind::WrongLastRevision => Ok(false),
            Err(e) => Err(FarmError::nats(format!("update job {}", job.record.id), e)),
        }
    }

    /// Applies `change` to the current record until the compare-and-set succeeds. `change`
    /// returns `false` to leave the record as it is. Returns the record as it ended (`None`:
    /// no such job).
    pub async fn update_job(
        &self,
        id: &str,
        mut change: impl FnMut(&mut FarmJob) -> bool,
    ) -> Result<Option<FarmJob>, FarmError> {
        loop {
            let Some((mut job, revision)) = self.job(id).await? else {
                return Ok(None);
            };
            if !change(&mut job) {
                return Ok(Some(job));
            }
            if self.replace_job(&job, revision).await? {
                return Ok(Some(job));
            }
        }
    }

    /// Announces an event of `job` to every replica's watchers (fire and forget).
    pub async fn publish_event(&self, job: &str, event: &BakeEvent) {
        let bytes = serde_json::to_vec(event).expect("events serialise");
        if let Err(e) = self.client.publish(events_subject(job), bytes.into()).await {
            tracing::warn!(%job, "cannot publish event: {e}");
        }
    }

    /// The completion record of a unit, if it finished.
    pub async fn unit_done(&self, job: &str, unit: &str) -> Result<Option<UnitDone>, FarmError> {
        let value = self
            .units
            .get(unit_key(job, unit))
            .await
            .map_err(|e| FarmError::nats(format!("read unit {unit} of job {job}"), e))?;
        Ok(value.and_then(|v| serde_json::from_slice(&v).ok()))
    }

    /// Records that a unit finished.
    pub async fn record_unit(
        &self,
        job: &str,
        unit: &str,
        done: &UnitDone,
    ) -> Result<(), FarmError> {
        let bytes = serde_json::to_vec(done).expect("records serialise");
        self.units
            .put(unit_key(job, unit), bytes.into())
            .await
            .map(|_| ())
            .map_err(|e| FarmError::nats(format!("record unit {unit} of job {job}"), e))
    }
}
