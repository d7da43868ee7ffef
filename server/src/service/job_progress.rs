//! The bake engine's [`Progress`] hook for one job: records the stage and progress in the job,
//! announces them as [`BakeEvent`]s, and stops the bake when the job is cancelled.
//!
//! Cancellation: the engine calls [`Progress::stage`] and [`Progress::advance`] from its rayon
//! workers many times a second. Once the job's cancel flag is set, the next such call unwinds
//! with a [`Cancelled`] payload (`resume_unwind`, so no panic message is printed); rayon carries
//! it out of the parallel loop, each worker stopping at its next step, and the runner catches it
//! and marks the job cancelled. The engine holds no lock or file across these calls that
//! outlives the bake (its caches write temp files and rename them), so unwinding leaves nothing
//! half-done behind.
//!
//! Invariant: events are throttled (at most one progress event per [`EMIT_INTERVAL`] per job), so
//! a bake reporting a million texels does not flood subscribers.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use lightfarm_proto::api::BakeEvent;

use super::jobs::Shared;
use crate::bake::progress::Progress;

/// Least time between two progress events of one job.
pub const EMIT_INTERVAL: Duration = Duration::from_millis(100);

/// The unwind payload of a cancelled bake.
#[derive(Debug)]
pub struct Cancelled;

/// Progress of one running job.
pub struct JobProgress {
    shared: Arc<Shared>,
    id: String,
    cancel: Arc<AtomicBool>,
    done: AtomicU64,
    total: AtomicU64,
    last_emit: Mutex<Instant>,
}

impl JobProgress {
    pub(super) fn new(shared: Arc<Shared>, id: String, cancel: Arc<AtomicBool>) -> JobProgress {
        JobProgress {
            shared,
            id,
            cancel,
            done: AtomicU64::new(0),
            total: AtomicU64::new(0),
            last_emit: Mutex::new(Instant::now()),
        }
    }

    fn stop_if_cancelled(&self) {
        if self.cancel.load(Ordering::Relaxed) {
            std::panic::resume_unwind(Box::new(Cancelled));
        }
    }

    fn publish(&self, stage_began: Option<(&str, u64)>) {
        let mut inner = self.shared.inner.lock().unwrap();
        let Some(job) = inner.jobs.get_mut(&self.id) else {
            return;
        };
        let record = &mut job.record;
        if let Some((name, total)) = stage_began {
            record.stage = Some(name.to_string());
            record.stages_seen += 1;
            record.stage_total = total;
            record.stage_done = 0;
            let _ = job.events.send(BakeEvent::Stage {
                stage: name.to_string(),
                total,
            });
        } else {
            record.stage_done = self.done.load(Ordering::Relaxed);
            record.stage_total = self.total.load(Ordering::Relaxed);
        }
        let fraction = if record.stage_total == 0 {
            0.0
        } else {
            (record.stage_done as f64 / record.stage_total as f64).min(1.0)
        };
        let expected = record.expected_stages.max(record.stages_seen).max(1);
        let overall = ((record.stages_seen.saturating_sub(1)) as f64 + fraction) / expected as f64;
        // Never backwards, never done before the bundle is stored.
        record.overall = record.overall.max(overall.min(0.99));
        if stage_began.is_none() {
            let _ = job.events.send(BakeEvent::Progress {
                stage: record.stage.clone().unwrap_or_default(),
                done: record.stage_done,
                total: record.stage_total,
                overall: record.overall,
            });
        }
    }
}

impl JobProgress {
    /// Records `bytes` as the bundle's final leading bytes and announces them.
    pub fn publish_prefix(&self, bytes: Vec<u8>, sections: Vec<String>) {
        let mut inner = self.shared.inner.lock().unwrap();
        let Some(job) = inner.jobs.get_mut(&self.id) else {
            return;
        };
        let len = bytes.len() as u64;
        job.prefix = Some(Arc::new(bytes));
        let _ = job.events.send(BakeEvent::Sections {
            sections,
            bytes: len,
        });
    }
}

impl Progress for JobProgress {
    fn stage(&self, name: &str, total: u64) {
        self.stop_if_cancelled();
        self.done.store(0, Ordering::Relaxed);
        self.total.store(total, Ordering::Relaxed);
        self.publish(Some((name, total)));
        *self.last_emit.lock().unwrap() = Instant::now();
    }

    fn advance(&self, n: u64) {
        self.stop_if_cancelled();
        let done = self.done.fetch_add(n, Ordering::Relaxed) + n;
        let total = self.total.load(Ordering::Relaxed);
        // Only one worker at a time considers emitting; the others go straight back to work.
        let Ok(mut last) = self.last_emit.try_lock() else {
            return;
        };
        if last.elapsed() >= EMIT_INTERVAL || done == total {
            *last = Instant::now();
            drop(last);
            self.publish(None);
        }
    }
}
