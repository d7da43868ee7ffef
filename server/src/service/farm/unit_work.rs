//! One bake unit on a worker: the job's scene laid out in a scratch directory, the unit's inputs
//! fetched from the object store into the worker's cache directory, the engine's
//! [`run_unit`] on the worker's rayon pool, the files it wrote
//! uploaded, and its completion recorded in KV before the message is acked.
//!
//! Cancellation works as in the embedded service ([`crate::service::job_progress`]): the
//! engine's progress hook ([`CancelHook`]) unwinds with a [`Cancelled`] payload once the job's
//! flag is set (by a message on the job's cancel subject), and the unwind is caught here.
//!
//! Invariants:
//! - A unit's completion is recorded only after all its outputs are in the object store, and
//!   the message is acked only after the record, so a worker dying at any point leaves the unit
//!   either recorded (and skipped when delivered again) or delivered again and rerun.
//! - A rerun writes identical bytes (units are deterministic), so a redelivery is harmless.
//! - A unit of a job that is final, or of an earlier attempt, is dropped without running.
//! - The worker's operator cache stays within its byte budget: it is trimmed
//!   least-recently-used after every unit and bake ([`WorkerContext::trim_cache`]).

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use async_nats::jetstream::{self, AckKind};

use super::blob_store::FarmStore;
use super::cache_sync;
use super::connection::{Farm, PROGRESS_ACK_EVERY};
use super::job_state::{UnitDone, UnitMessage};
use crate::bake::cache::shape::ShapeCache;
use crate::bake::memory::release_freed;
use crate::bake::progress::Progress;
use crate::bake::units::{run_unit, unit_inputs, BakeUnit, UnitScene};
use crate::service::executor::{prepare_scene, ScratchDir};
use crate::service::job_progress::Cancelled;
use crate::service::jobs::JobRecord;
use crate::service::operator_cache;
use lightfarm_proto::scene::Scene;

/// Cancel flags per (job, attempt), set by the worker's cancel subscription.
#[derive(Default)]
pub struct CancelFlags(Mutex<HashMap<(String, u64), Arc<AtomicBool>>>);

impl CancelFlags {
    pub fn flag(&self, job: &str, attempt: u64) -> Arc<AtomicBool> {
        self.0
            .lock()
            .unwrap()
            .entry((job.to_string(), attempt))
            .or_default()
            .clone()
    }

    pub fn cancel(&self, job: &str, attempt: u64) {
        self.flag(job, attempt).store(true, Ordering::SeqCst);
    }
}

/// The engine's progress hook on a worker: it only stops the work when the job is cancelled.
pub struct CancelHook(pub Arc<AtomicBool>);

impl CancelHook {
    fn stop_if_cancelled(&self) {
        if self.0.load(Ordering::Relaxed) {
            std::panic::resume_unwind(Box::new(Cancelled));
        }
    }
}

impl Progress for CancelHook {
    fn stage(&self, _: &str, _: u64) {
        self.stop_if_cancelled();
    }

    fn advance(&self, _: u64) {
        self.stop_if_cancelled();
    }
}

/// What a worker needs to run units and assemble bundles.
pub struct WorkerContext {
    pub farm: Arc<Farm>,
    pub store: Arc<FarmStore>,
    /// The local operator cache (a [`ShapeCache`] directory).
    pub cache_dir: PathBuf,
    /// Parent of per-unit scratch directories.
    pub scratch: PathBuf,
    pub pool: Arc<rayon::ThreadPool>,
    pub cancels: CancelFlags,
    /// This worker's name in logs and completion records.
    pub name: String,
    pub counter: AtomicU64,
    /// Byte budget of `cache_dir`, trimmed least-recently-used after each unit and bake.
    pub cache_bytes: u64,
    /// The last job's scene for its units, by job id ([`WorkerContext::job_scene`]); dropped
    /// when the unit lane finds no work ([`WorkerContext::forget_job_scene`]).
    pub last_scene: Mutex<Option<(String, Arc<JobScene>)>>,
}

/// A job's [`UnitScene`] and the scratch directory its mesh files lie in (removed when the
/// last unit using it is done and another job's scene has replaced it).
pub struct JobScene {
    pub units: UnitScene,
    _dir: ScratchDir,
}

impl WorkerContext {
    /// The job's scene and assets in a fresh scratch directory (removed when the guard drops).
    /// Trims the local operator cache to its budget ([`operator_cache::trim`]) and says so when
    /// it removed anything. Safe at any time: a unit's outputs are uploaded before it is
    /// recorded, an assembler downloads what it reads again, and an entry gone mid-bake is a
    /// cache miss (recomputed), never an error.
    pub async fn trim_cache(&self) {
        let (dir, budget) = (self.cache_dir.clone(), self.cache_bytes);
        let Ok(report) =
            tokio::task::spawn_blocking(move || operator_cache::trim(&dir, budget)).await
        else {
            return;
        };
        if report.removed_files > 0 {
            crate::say!(
                "lightfarm worker {}: trimmed operator cache: removed {} files ({} bytes), {} bytes kept (budget {budget})",
                self.name, report.removed_files, report.removed_bytes, report.bytes
            );
        }
    }

    /// The job's scene and assets in a fresh scratch directory (removed when the guard drops).
    pub fn prepare(&self, record: &JobRecord) -> Result<(Scene, ScratchDir), String> {
        let dir = self.scratch.join(format!(
            "{}-{}",
            &record.id[..16],
            self.counter.fetch_add(1, Ordering::Relaxed)
        ));
        prepare_scene(self.store.as_ref(), &record.scene, &record.settings, &dir)
    }

    /// The job's scene as its units read it ([`UnitScene`]: validated, its shape plan and ray
    /// level made once), kept for the job's next units on this worker: units of one bake run
    /// one after another, and remaking these per unit cost more than the units themselves at
    /// 1,000 blocks. A job's scene and settings never change under its id.
    pub fn job_scene(&self, record: &JobRecord) -> Result<Arc<JobScene>, String> {
        let mut last = self.last_scene.lock().unwrap_or_else(|p| p.into_inner());
        if let Some((id, scene)) = &*last {
            if *id == record.id {
                return Ok(scene.clone());
            }
        }
        let (scene, dir) = self.prepare(record)?;
        let units = UnitScene::new(scene, &dir.0).map_err(|e| e.to_string())?;
        let scene = Arc::new(JobScene { units, _dir: dir });
        *last = Some((record.id.clone(), scene.clone()));
        Ok(scene)
    }

    /// Lets go of the kept job scene (its geometry and tracers, and its scratch directory) and
    /// hands the freed pages back to the system: the unit lane calls it when a pull finds no
    /// work.
    pub fn forget_job_scene(&self) {
        let kept = self
            .last_scene
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take();
        if let Some((job, _)) = &kept {
            tracing::info!(%job, "idle: the kept job scene is let go");
            drop(kept);
            release_freed();
        }
    }

    /// Runs `work` on the worker's pool, catching a cancel unwind and panics.
    pub fn on_pool<T>(&self, work: impl FnOnce() -> Result<T, String> + Send) -> Outcome<T>
    where
        T: Send,
    {
        let result =
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| self.pool.install(work)));
        match result {
            Ok(Ok(value)) => Outcome::Done(value),
            Ok(Err(message)) => Outcome::Failed(message),
            Err(payload) if payload.is::<Cancelled>() => Outcome::Cancelled,
            Err(payload) => {
                let message = payload
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_else(|| "unknown panic".into());
                Outcome::Failed(format!("internal error: {message}"))
            }
        }
    }
}

/// How a piece of work ended.
pub enum Outcome<T> {
    Done(T),
    Cancelled,
    Failed(String),
}

/// Sends a progress ack for `message` every [`PROGRESS_ACK_EVERY`] until dropped.
pub struct KeepAlive(tokio::task::JoinHandle<()>);

impl KeepAlive {
    pub fn start(message: &jetstream::Message) -> KeepAlive {
        let message = message.clone();
        KeepAlive(tokio::spawn(async move {
            let mut tick = tokio::time::interval(PROGRESS_ACK_EVERY);
            tick.tick().await;
            loop {
                tick.tick().await;
                if let Err(e) = message.ack_with(AckKind::Progress).await {
                    tracing::warn!("progress ack: {e}");
                }
            }
        }))
    }
}

impl Drop for KeepAlive {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// The blocking part of a unit: scene, inputs, run, outputs.
fn run_blocking(
    ctx: &WorkerContext,
    record: &JobRecord,
    unit_name: &str,
    cancel: Arc<AtomicBool>,
) -> Outcome<Vec<PathBuf>> {
    let scene = match ctx.job_scene(record) {
        Ok(scene) => scene,
        Err(message) => return Outcome::Failed(message),
    };
    let Some(unit) = BakeUnit::parse(unit_name) else {
        return Outcome::Failed(format!("unit {unit_name:?} is not a bake unit"));
    };
    let inputs = match unit_inputs(&scene.units, &unit) {
        Ok(inputs) => inputs,
        Err(e) => return Outcome::Failed(format!("unit {unit_name}: {e}")),
    };
    if let Err(e) = ctx.farm.block_on(cache_sync::download(
        &ctx.farm.operators,
        &ctx.cache_dir,
        &inputs,
    )) {
        return Outcome::Failed(e.to_string());
    }
    let cache = match ShapeCache::open(&ctx.cache_dir) {
        Ok(cache) => cache,
        Err(e) => {
            return Outcome::Failed(format!("operator cache {}: {e}", ctx.cache_dir.display()))
        }
    };
    let hook = CancelHook(cancel);
    let outcome = ctx.on_pool(|| {
        run_unit(&scene.units, &cache, &unit, &hook).map_err(|e| format!("unit {unit_name}: {e}"))
    });
    match outcome {
        Outcome::Done(written) => match ctx.farm.block_on(cache_sync::upload(
            &ctx.farm.operators,
            &ctx.cache_dir,
            &written,
        )) {
            Ok(_) => Outcome::Done(written),
            Err(e) => Outcome::Failed(e.to_string()),
        },
        other => other,
    }
}

/// Handles one unit message to the end (acked, terminated, or left for redelivery when NATS
/// itself fails).
pub async fn handle_unit(ctx: Arc<WorkerContext>, message: jetstream::Message) {
    let Ok(unit) = serde_json::from_slice::<UnitMessage>(&message.payload) else {
        tracing::error!("unreadable unit message: dropped");
        let _ = message.ack_with(AckKind::Term).await;
        return;
    };
    let job = match ctx.farm.job(&unit.job).await {
        Ok(job) => job,
        Err(e) => {
            tracing::warn!("{e}; the unit will be delivered again");
            return;
        }
    };
    let record = match job {
        Some((job, _)) if job.attempt == unit.attempt && !job.record.state.is_final() => job.record,
        _ => {
            // Cancelled, finished, or superseded by a newer attempt.
            let _ = message.ack_with(AckKind::Term).await;
            return;
        }
    };
    if let Ok(Some(_)) = ctx.farm.unit_done(&unit.job, &unit.unit).await {
        let _ = message.ack().await;
        return;
    }
    let delivered = message.info().map(|i| i.delivered).unwrap_or(1);
    crate::say!(
        "lightfarm worker {}: started unit {} of job {} (delivery {delivered})",
        ctx.name,
        unit.unit,
        unit.job
    );
    let started = Instant::now();
    let keep_alive = KeepAlive::start(&message);
    let cancel = ctx.cancels.flag(&unit.job, unit.attempt);
    let outcome = {
        let ctx = ctx.clone();
        let unit_name = unit.unit.clone();
        tokio::task::spawn_blocking(move || run_blocking(&ctx, &record, &unit_name, cancel))
            .await
            .unwrap_or_else(|e| Outcome::Failed(format!("internal error: {e}")))
    };
    drop(keep_alive);
    let seconds = started.elapsed().as_secs_f64();
    let done = match outcome {
        Outcome::Cancelled => {
            crate::say!(
                "lightfarm worker {}: cancelled unit {} of job {}",
                ctx.name,
                unit.unit,
                unit.job
            );
            let _ = message.ack_with(AckKind::Term).await;
            return;
        }
        Outcome::Done(outputs) => UnitDone {
            outputs: outputs.iter().map(|p| cache_sync::object_name(p)).collect(),
            error: None,
            worker: ctx.name.clone(),
            seconds,
        },
        Outcome::Failed(message) => UnitDone {
            outputs: Vec::new(),
            error: Some(message),
            worker: ctx.name.clone(),
            seconds,
        },
    };
    if let Err(e) = ctx.farm.record_unit(&unit.job, &unit.unit, &done).await {
        tracing::warn!("{e}; the unit will be delivered again");
        return;
    }
    crate::say!(
        "lightfarm worker {}: finished unit {} of job {} in {seconds:.2} s",
        ctx.name,
        unit.unit,
        unit.job
    );
    if let Err(e) = message.double_ack().await {
        tracing::warn!("ack of unit {}: {e}", unit.unit);
    }
    ctx.trim_cache().await;
}
