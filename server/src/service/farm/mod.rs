//! The bake farm: `lightfarm serve --farm nats://…` replicas and `lightfarm worker --farm nats://…`
//! processes sharing their state through NATS JetStream instead of one machine's data directory.
//!
//! # Layout
//! - [`connection`]: connecting, and the streams, KV buckets and object stores every process
//!   creates if absent (names and subjects are the constants below).
//! - [`blob_store`]: [`blob_store::FarmStore`], the [`super::store::BlobStore`] on the object
//!   store, with per-team visibility markers in a KV bucket.
//! - [`job_state`]: job records in the jobs KV bucket, unit completion records, events.
//! - [`queue`]: [`queue::FarmJobs`], the [`super::jobs::JobQueue`] of a serve replica.
//! - [`cache_sync`]: operator-cache files between a worker's cache directory and the object store.
//! - [`unit_work`]: one bake unit on a worker (scene, inputs, `run_unit`, outputs, cancel).
//! - [`worker`]: the worker process: a coordinator lane (bake messages) and a unit lane.
//!
//! # Names
//! ```text
//! stream  LIGHTFARM_WORK (work-queue retention, explicit acks)
//!           lightfarm.work.bake   {job, attempt}                consumer "coordinators"
//!           lightfarm.work.unit   {job, attempt, unit}          consumer "units"
//! core    lightfarm.events.<job>  BakeEvent JSON (stage, progress, state)
//!         lightfarm.cancel.<job>  the attempt number being cancelled
//! KV      lightfarm_jobs          <job>                → FarmJob JSON
//!         lightfarm_units         <job>.<unit>         → UnitDone JSON (outputs or error)
//!         lightfarm_owners        <team>.<kind>.<hash> → empty (team may see the blob)
//! objects lightfarm_blobs         <kind>/<hash>        asset, scene and bundle bytes
//!         lightfarm_operators     <cache-relative path> operator-cache files
//! ```
//!
//! Invariants: serve replicas hold no state of their own (any replica answers for any job, and a
//! restarted one loses nothing); every unit is deterministic, so a unit run twice (redelivery
//! after a worker died, a coordinator re-publishing after its own death) writes identical bytes,
//! and the assembled bundle is byte-identical to the embedded bake's.

pub mod blob_store;
pub mod cache_sync;
pub mod connection;
pub mod job_state;
pub mod queue;
pub mod unit_work;
pub mod worker;

/// A farm failure (NATS, JetStream, or a record that does not parse), naming what it was doing.
#[derive(Debug, thiserror::Error)]
pub enum FarmError {
    #[error("farm: {what}: {message}")]
    Nats { what: String, message: String },
}

impl FarmError {
    /// Wraps any error with what was being done.
    pub fn nats(what: impl Into<String>, error: impl std::fmt::Display) -> FarmError {
        FarmError::Nats {
            what: what.into(),
            message: error.to_string(),
        }
    }
}

/// The work-queue stream.
pub const WORK_STREAM: &str = "LIGHTFARM_WORK";
pub const BAKE_SUBJECT: &str = "lightfarm.work.bake";
pub const UNIT_SUBJECT: &str = "lightfarm.work.unit";
pub const COORDINATOR_CONSUMER: &str = "coordinators";
pub const UNIT_CONSUMER: &str = "units";
pub const JOBS_BUCKET: &str = "lightfarm_jobs";
pub const UNITS_BUCKET: &str = "lightfarm_units";
pub const OWNERS_BUCKET: &str = "lightfarm_owners";
pub const BLOBS_BUCKET: &str = "lightfarm_blobs";
pub const OPERATORS_BUCKET: &str = "lightfarm_operators";

/// The core-NATS subject of a job's events.
pub fn events_subject(job: &str) -> String {
    format!("lightfarm.events.{job}")
}

/// The core-NATS subject a job's cancellation is announced on.
pub fn cancel_subject(job: &str) -> String {
    format!("lightfarm.cancel.{job}")
}

/// A string as a KV key token: `[A-Za-z0-9_-]` kept, every other byte as `=XX`.
pub fn key_token(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || b == b'_' || b == b'-' {
            out.push(b as char);
        } else {
            out.push_str(&format!("={b:02X}"));
        }
    }
    out
}
