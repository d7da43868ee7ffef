//! `lightfarm worker --farm nats://…`: the worker process. Two lanes pull from the work stream:
//!
//! - the **unit lane** takes one unit message at a time and runs it on the worker's rayon pool
//!   ([`super::unit_work`]): the CPU work;
//! - the **coordinator lane** takes bake messages, up to [`COORDINATIONS`] at once, each on its
//!   own task (`coordinate`): plan the bake's units, publish those of phase 0, wait (asleep
//!   between looks at the completion records) until all are recorded, then the next phase, then
//!   assemble the bundle from the units' files (every cache lookup hits), store it and mark the
//!   job succeeded.
//!
//! Coordinators use no CPU while they wait, and they never wait for their own lane, so one
//! worker alone finishes a bake (its unit lane runs the units its coordinator publishes).
//!
//! Invariants:
//! - Every delivered message is acked only when its work is recorded; while working, a progress
//!   ack goes out every few seconds, so only a dead worker's messages are delivered again.
//! - A coordinator that dies loses nothing: its bake message is delivered again, the new
//!   coordinator skips recorded units and publishes the others again (JetStream's duplicate
//!   window drops copies of messages still queued; a unit run twice is harmless).
//! - The job record is written by compare-and-set and only while it is `running` with the
//!   coordinator's attempt, so a cancel (from any replica) always wins.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use async_nats::jetstream::{self, AckKind};
use async_nats::HeaderMap;
use futures_util::StreamExt;

use lightfarm_proto::api::{BakeEvent, JobState, StageTiming};

use super::blob_store::FarmStore;
use super::cache_sync;
use super::connection::Farm;
use super::job_state::{BakeMessage, FarmJob, UnitMessage};
use super::unit_work::{handle_unit, CancelHook, KeepAlive, Outcome, WorkerContext};
use super::{FarmError, COORDINATOR_CONSUMER, UNIT_CONSUMER, UNIT_SUBJECT};
use crate::bake::cache::shape::ShapeCache;
use crate::bake::units::{plan, unit_inputs};
use crate::bake::{bake, BakeOptions};
use crate::service::executor::{encode_bundle, open_memo};
use crate::service::jobs::unix_now;
use crate::service::store::BlobKind;

/// Bakes one worker coordinates at once.
pub const COORDINATIONS: usize = 4;
/// How often a waiting coordinator looks at the completion records and the job's state.
pub const COMPLETION_POLL: Duration = Duration::from_millis(250);
/// How long a pull waits for a message before asking again.
const PULL_EXPIRES: Duration = Duration::from_secs(5);

/// Arguments of `lightfarm worker`.
pub struct WorkerOptions {
    pub farm: String,
    /// Local operator cache.
    pub cache: PathBuf,
    /// Threads of the unit lane's rayon pool (0: one per core).
    pub threads: usize,
    /// Byte budget of the local operator cache (`<cache>/operators`), trimmed
    /// least-recently-used after each unit and each bake this worker coordinates.
    pub cache_bytes: u64,
}

/// Connects and works until the process is stopped.
pub async fn run(options: WorkerOptions) -> Result<(), FarmError> {
    let farm = Arc::new(Farm::connect(&options.farm).await?);
    let threads = match options.threads {
        0 => std::thread::available_parallelism().map_or(2, |n| n.get()),
        n => n,
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("unit-worker-{i}"))
        .build()
        .map_err(|e| FarmError::nats("worker pool", e))?;
    let name = format!(
        "{}-{}",
        std::env::var("HOSTNAME").unwrap_or_else(|_| "worker".into()),
        std::process::id()
    );
    let scratch = options.cache.join("work").join(&name);
    let _ = std::fs::remove_dir_all(&scratch);
    let ctx = Arc::new(WorkerContext {
        store: Arc::new(FarmStore::new(farm.clone())),
        farm: farm.clone(),
        cache_dir: options.cache.join("operators"),
        scratch,
        pool: Arc::new(pool),
        cancels: Default::default(),
        name: name.clone(),
        counter: AtomicU64::new(0),
        cache_bytes: options.cache_bytes,
        last_scene: Mutex::new(None),
    });

    let mut cancels = farm
        .client
        .subscribe(super::cancel_subject("*"))
        .await
        .map_err(|e| FarmError::nats("subscribe to cancels", e))?;
    let cancel_ctx = ctx.clone();
    tokio::spawn(async move {
        while let Some(message) = cancels.next().await {
            let job = message.subject.rsplit('.').next().unwrap_or_default();
            if let Ok(attempt) = std::str::from_utf8(&message.payload)
                .unwrap_or_default()
                .parse::<u64>()
            {
                cancel_ctx.cancels.cancel(job, attempt);
            }
        }
    });

    let coordinators = tokio::spawn(coordinator_lane(ctx.clone()));
    let units = tokio::spawn(unit_lane(ctx.clone()));
    crate::say!("lightfarm worker {name}: ready ({threads} threads)");
    tokio::select! {
        r = coordinators => r.map_err(|e| FarmError::nats("coordinator lane", e))?,
        r = units => r.map_err(|e| FarmError::nats("unit lane", e))?,
    }
}

/// Pulls one message at a time from `consumer` (none is held while the lane is busy).
async fn pull_one(
    consumer: &jetstream::consumer::Consumer<jetstream::consumer::pull::Config>,
) -> Result<Option<jetstream::Message>, FarmError> {
    let mut batch = consumer
        .fetch()
        .max_messages(1)
        .expires(PULL_EXPIRES)
        .messages()
        .await
        .map_err(|e| FarmError::nats("pull", e))?;
    match batch.next().await {
        Some(Ok(message)) => Ok(Some(message)),
        Some(Err(e)) => Err(FarmError::nats("pull", e)),
        None => Ok(None),
    }
}

async fn unit_lane(ctx: Arc<WorkerContext>) -> Result<(), FarmError> {
    let consumer = ctx.farm.consumer(UNIT_CONSUMER).await?;
    loop {
        match pull_one(&consumer).await {
            Ok(Some(message)) => handle_unit(ctx.clone(), message).await,
            // Idle: a kept job scene would hold its level's geometry until the next job.
            Ok(None) => ctx.forget_job_scene(),
            Err(e) => {
                tracing::warn!("{e}");
                tokio::time::sleep(Duration::from_secs(1)).await;
            }
        }
    }
}

async fn coordinator_lane(ctx: Arc<WorkerContext>) -> Result<(), FarmError> {
    let consumer = ctx.farm.consumer(COORDINATOR_CONSUMER).await?;
    let slots = Arc::new(tokio::sync::Semaphore::new(COORDINATIONS));
    loop {
        let permit = slots.clone().acquire_owned().await.expect("never closed");
        match pull_one(&consumer).await {
            Ok(Some(message)) => {
                let ctx = ctx.clone();
                tokio::spawn(async move {
                    coordinate(ctx, message).await;
                    drop(permit);
                });
            }
            Ok(None) => {}
            Err(e) => {
                tracing::warn!("{e}");
                tokio::time::sleep(Duration::from_secs(1)).await;
            }
        }
    }
}

/// Changes the job record if it is still `running` this attempt; `false` when it is not (the
/// coordinator then stops).
async fn while_running(
    farm: &Farm,
    id: &str,
    attempt: u64,
    mut change: impl FnMut(&mut FarmJob),
) -> bool {
    let mut running = false;
    let result = farm
        .update_job(id, |job| {
            running = job.attempt == attempt && job.record.state == JobState::Running;
            if running {
                change(job);
            }
            running
        })
        .await;
    if let Err(e) = result {
        tracing::warn!(job = %id, "{e}");
    }
    running
}

/// Coordinates one bake message to the end.
async fn coordinate(ctx: Arc<WorkerContext>, message: jetstream::Message) {
    let Ok(bake_message) = serde_json::from_slice::<BakeMessage>(&message.payload) else {
        tracing::error!("unreadable bake message: dropped");
        let _ = message.ack_with(AckKind::Term).await;
        return;
    };
    let farm = &ctx.farm;
    let (id, attempt) = (bake_message.job.clone(), bake_message.attempt);
    // Take the job: queued → running (a redelivered message finds it running already).
    let mut took = false;
    let taken = farm
        .update_job(&id, |job| {
            took = job.attempt == attempt && !job.record.state.is_final();
            if took && job.record.state == JobState::Queued {
                job.record.state = JobState::Running;
                job.record.error = None;
                job.record.stages.clear();
            }
            took
        })
        .await;
    let job = match taken {
        Ok(Some(job)) if took => job,
        Ok(_) => {
            let _ = message.ack().await; // final, superseded or gone: nothing to do
            return;
        }
        Err(e) => {
            tracing::warn!("{e}; the bake will be delivered again");
            return;
        }
    };
    farm.publish_event(&id, &job.record.state_event()).await;
    let keep_alive = KeepAlive::start(&message);
    tracing::info!(job = %id, attempt, "coordinating");
    let result = run_phases_and_assemble(&ctx, &job).await;
    drop(keep_alive);
    let final_record = match result {
        Ok(Some(finished)) => {
            let Finished {
                bundle,
                bundle_bytes,
                stages,
                shape_keys,
            } = finished;
            for owner in &job.record.owners {
                if let Err(e) = ctx.store.allow(owner, BlobKind::Bundle, &bundle).await {
                    tracing::error!(job = %id, "cannot grant bundle: {e}");
                }
            }
            let mut record = None;
            while_running(farm, &id, attempt, |j| {
                // Owners added while it ran see it too.
                j.record.state = JobState::Succeeded;
                j.record.bundle = Some(bundle.clone());
                j.record.bundle_bytes = Some(bundle_bytes);
                j.record.stages = stages.clone();
                j.record.shape_keys = shape_keys.clone();
                j.record.overall = 1.0;
                j.record.error = None;
                j.record.finished_at = Some(unix_now());
                record = Some(j.clone());
            })
            .await;
            if let Some(j) = &record {
                for owner in &j.record.owners {
                    let _ = ctx.store.allow(owner, BlobKind::Bundle, &bundle).await;
                }
            }
            record
        }
        Ok(None) => None, // cancelled or superseded: whoever changed the record announced it
        Err(message) => {
            let mut record = None;
            while_running(farm, &id, attempt, |j| {
                j.record.state = JobState::Failed;
                j.record.error = Some(message.clone());
                j.record.finished_at = Some(unix_now());
                record = Some(j.clone());
            })
            .await;
            record
        }
    };
    if let Some(job) = final_record {
        tracing::info!(job = %id, state = job.record.state.name(), "bake finished");
        farm.publish_event(&id, &job.record.state_event()).await;
    }
    let _ = message.double_ack().await;
    ctx.trim_cache().await;
}

/// What a finished bake produced.
struct Finished {
    bundle: String,
    bundle_bytes: u64,
    stages: Vec<StageTiming>,
    shape_keys: Vec<String>,
}

/// The plan of a bake: unit names per phase, and every cache file any unit may read.
fn plan_blocking(
    ctx: &WorkerContext,
    job: &FarmJob,
) -> Result<(Vec<Vec<String>>, Vec<PathBuf>), String> {
    let scene = ctx.job_scene(&job.record)?;
    let phases = plan(&scene.units).map_err(|e| format!("plan: {e}"))?;
    let mut inputs = Vec::new();
    for unit in phases.iter().flatten() {
        inputs.extend(unit_inputs(&scene.units, unit).map_err(|e| format!("plan: {e}"))?);
    }
    let names = phases
        .iter()
        .map(|phase| phase.iter().map(|u| u.name()).collect())
        .collect();
    Ok((names, inputs))
}

/// `Ok(None)`: the job stopped running (cancelled, or a newer attempt).
async fn run_phases_and_assemble(
    ctx: &Arc<WorkerContext>,
    job: &FarmJob,
) -> Result<Option<Finished>, String> {
    let farm = &ctx.farm;
    let (id, attempt) = (job.record.id.clone(), job.attempt);
    let planned = {
        let (ctx, job) = (ctx.clone(), job.clone());
        tokio::task::spawn_blocking(move || plan_blocking(&ctx, &job))
            .await
            .map_err(|e| format!("internal error: {e}"))??
    };
    let (phases, mut files) = planned;
    let total_units: usize = phases.iter().map(Vec::len).sum();
    let mut done_units = 0usize;
    let mut stages = Vec::new();
    for (k, phase) in phases.iter().enumerate() {
        let stage = format!("units, phase {} of {}", k + 1, phases.len());
        let began = Instant::now();
        if !while_running(farm, &id, attempt, |j| {
            j.record.stage = Some(stage.clone());
            j.record.stages_seen += 1;
            j.record.stage_done = 0;
            j.record.stage_total = phase.len() as u64;
        })
        .await
        {
            return Ok(None);
        }
        farm.publish_event(
            &id,
            &BakeEvent::Stage {
                stage: stage.clone(),
                total: phase.len() as u64,
            },
        )
        .await;
        let mut pending: Vec<&String> = Vec::new();
        for unit in phase {
            match farm.unit_done(&id, unit).await {
                Ok(Some(done)) if done.error.is_none() => {
                    files.extend(done.outputs.iter().map(PathBuf::from));
                    done_units += 1;
                }
                _ => {
                    publish_unit(farm, &id, attempt, unit).await?;
                    pending.push(unit);
                }
            }
        }
        let mut last_report = Instant::now();
        let mut reported = usize::MAX;
        loop {
            let phase_done = phase.len() - pending.len();
            if phase_done != reported
                && (pending.is_empty() || last_report.elapsed() >= Duration::from_millis(500))
            {
                reported = phase_done;
                last_report = Instant::now();
                let overall = (done_units as f64 / (total_units + 1) as f64).min(0.99);
                if !while_running(farm, &id, attempt, |j| {
                    j.record.stage_done = phase_done as u64;
                    j.record.overall = j.record.overall.max(overall);
                })
                .await
                {
                    return Ok(None);
                }
                farm.publish_event(
                    &id,
                    &BakeEvent::Progress {
                        stage: stage.clone(),
                        done: phase_done as u64,
                        total: phase.len() as u64,
                        overall,
                    },
                )
                .await;
            }
            if pending.is_empty() {
                break;
            }
            tokio::time::sleep(COMPLETION_POLL).await;
            match farm.job(&id).await {
                Ok(Some((j, _))) if j.attempt == attempt && j.record.state == JobState::Running => {
                }
                Ok(_) => return Ok(None),
                Err(e) => tracing::warn!(job = %id, "{e}"),
            }
            let mut still = Vec::new();
            for unit in pending {
                match farm.unit_done(&id, unit).await {
                    Ok(Some(done)) => {
                        if let Some(error) = done.error {
                            return Err(error);
                        }
                        files.extend(done.outputs.iter().map(PathBuf::from));
                        done_units += 1;
                    }
                    Ok(None) => still.push(unit),
                    Err(e) => {
                        tracing::warn!(job = %id, "{e}");
                        still.push(unit);
                    }
                }
            }
            pending = still;
        }
        stages.push(StageTiming {
            stage,
            seconds: began.elapsed().as_secs_f64(),
        });
    }

    let stage = "assembling the bundle".to_string();
    if !while_running(farm, &id, attempt, |j| {
        j.record.stage = Some(stage.clone());
        j.record.stages_seen += 1;
        j.record.stage_done = 0;
        j.record.stage_total = 1;
    })
    .await
    {
        return Ok(None);
    }
    farm.publish_event(
        &id,
        &BakeEvent::Stage {
            stage: stage.clone(),
            total: 1,
        },
    )
    .await;
    let began = Instant::now();
    files.sort();
    files.dedup();
    let cancel = ctx.cancels.flag(&id, attempt);
    let assembled = {
        let (ctx, job) = (ctx.clone(), job.clone());
        tokio::task::spawn_blocking(move || assemble_blocking(&ctx, &job, &files, cancel))
            .await
            .map_err(|e| format!("internal error: {e}"))?
    };
    let (bytes, shape_keys) = match assembled {
        Outcome::Done(done) => done,
        Outcome::Cancelled => return Ok(None),
        Outcome::Failed(message) => return Err(message),
    };
    let bundle = ctx
        .store
        .write(BlobKind::Bundle, &bytes)
        .await
        .map_err(|e| e.to_string())?;
    stages.push(StageTiming {
        stage,
        seconds: began.elapsed().as_secs_f64(),
    });
    Ok(Some(Finished {
        bundle,
        bundle_bytes: bytes.len() as u64,
        stages,
        shape_keys,
    }))
}

async fn publish_unit(farm: &Farm, job: &str, attempt: u64, unit: &str) -> Result<(), String> {
    let message = UnitMessage {
        job: job.to_string(),
        attempt,
        unit: unit.to_string(),
    };
    let mut headers = HeaderMap::new();
    headers.insert(
        "Nats-Msg-Id",
        format!("unit/{job}/{attempt}/{unit}").as_str(),
    );
    let ack = farm
        .jetstream
        .publish_with_headers(
            UNIT_SUBJECT,
            headers,
            serde_json::to_vec(&message).expect("serialises").into(),
        )
        .await
        .map_err(|e| format!("publish unit {unit}: {e}"))?;
    ack.await.map_err(|e| format!("publish unit {unit}: {e}"))?;
    Ok(())
}

/// Fetches every unit's files into the local cache and runs the ordinary bake on it (every
/// lookup hits), encoding the bundle as the embedded service does.
fn assemble_blocking(
    ctx: &WorkerContext,
    job: &FarmJob,
    files: &[PathBuf],
    cancel: Arc<std::sync::atomic::AtomicBool>,
) -> Outcome<(Vec<u8>, Vec<String>)> {
    let (scene, dir) = match ctx.prepare(&job.record) {
        Ok(prepared) => prepared,
        Err(message) => return Outcome::Failed(message),
    };
    if let Err(e) = ctx.farm.block_on(cache_sync::download(
        &ctx.farm.operators,
        &ctx.cache_dir,
        files,
    )) {
        return Outcome::Failed(e.to_string());
    }
    let cache = match ShapeCache::open(&ctx.cache_dir) {
        Ok(cache) => cache,
        Err(e) => return Outcome::Failed(format!("operator cache: {e}")),
    };
    let hook = CancelHook(cancel);
    let scene_dir: &Path = &dir.0;
    ctx.on_pool(|| {
        let options = BakeOptions {
            cache: Some(cache),
            ..BakeOptions::default()
        };
        let (bundle, _) = bake(&scene, scene_dir, &options, &hook).map_err(|e| e.to_string())?;
        let keys = bundle.shapes.iter().map(|s| s.key.clone()).collect();
        let memo = open_memo(&ctx.cache_dir, &scene);
        Ok((encode_bundle(&scene, &bundle, memo.as_ref()), keys))
    })
}
