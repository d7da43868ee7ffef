//! Bake jobs: the [`JobQueue`] seam the handlers talk to, and its embedded implementation
//! [`LocalJobs`] (a bounded in-process queue, runner threads sharing one rayon pool, job records
//! persisted as JSON under `<data>/jobs/`).
//!
//! Invariants:
//! - A job's id is the content hash of (scene id, effective settings); submitting the same bake
//!   again returns the existing job (finished: a cache hit, no work) and lets the new team see it.
//! - Every state change is written to `<data>/jobs/<id>.json` (temp file + rename) before it is
//!   announced, so after a kill -9 a restart finds each job as it was last announced: finished
//!   jobs are served, queued and running ones are queued again (the bake is deterministic, so a
//!   rerun gives the same bundle).
//! - The queue holds at most `queue_capacity` waiting jobs; a submission beyond that is refused
//!   with a retry delay and allocates nothing that outlives the request.
//! - Bake work runs on the runner threads and the rayon pool, never on the async runtime.
//! - Another team's job is reported as absent, never as forbidden.

use std::collections::{BTreeSet, HashMap};
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Instant, SystemTime};

use serde::{Deserialize, Serialize};
use tokio::sync::broadcast;

use lightfarm_proto::api::{BakeEvent, BakeStatus, JobState, StageTiming};

use super::job_progress::{Cancelled, JobProgress};
use super::store::{BlobKind, BlobStore};

/// A bake to run: what the handler validated.
#[derive(Clone, Debug)]
pub struct BakeRequest {
    pub id: String,
    pub scene: String,
    /// Overrides of the scene's settings (a JSON object).
    pub settings: serde_json::Value,
    pub team: String,
    /// Blobs the bake reads (the scene and its assets); pinned while it waits or runs.
    pub inputs: Vec<(BlobKind, String)>,
    /// Stages the bake is expected to report (for the overall progress fraction).
    pub expected_stages: usize,
}

/// What a finished bake produced.
pub struct BakeOutput {
    pub bundle: Vec<u8>,
    pub stage_seconds: Vec<(String, f64)>,
    pub shape_keys: Vec<String>,
    pub shapes_from_cache: u64,
    pub shapes_computed: u64,
}

/// Runs one bake; the embedded implementation is [`super::executor::PipelineExecutor`].
pub trait BakeExecutor: Send + Sync + 'static {
    fn run(
        &self,
        scene: &str,
        settings: &serde_json::Value,
        progress: &JobProgress,
    ) -> Result<BakeOutput, String>;
}

/// Why a submission was refused.
#[derive(Debug, thiserror::Error)]
pub enum QueueError {
    #[error("the bake queue is full ({capacity} waiting); retry in {retry_after} s")]
    Full { capacity: usize, retry_after: u64 },
    #[error("job store: {0}")]
    Io(String),
}

/// Counters for `/metrics`.
#[derive(Clone, Debug, Default)]
pub struct QueueMetrics {
    pub depth: u64,
    pub by_state: Vec<(JobState, u64)>,
    /// Summed over finished bakes, per stage.
    pub stage_seconds: Vec<(String, f64)>,
    pub bake_cache_hits: u64,
    pub bake_cache_misses: u64,
    pub shape_cache_hits: u64,
    pub shape_cache_misses: u64,
}

/// The job queue the handlers see. Everything is per team: a job another team cannot see is
/// `None`.
pub trait JobQueue: Send + Sync + 'static {
    /// Queues the bake, or returns the existing job with the same id (see the module doc).
    fn submit(&self, request: BakeRequest) -> Result<BakeStatus, QueueError>;
    fn status(&self, team: &str, id: &str) -> Option<BakeStatus>;
    /// Every job the team can see, in no particular order (`GET /v1/bakes` sorts and pages).
    fn list(&self, team: &str) -> Vec<BakeStatus>;
    /// Cancels a queued or running job (a finished one is returned unchanged).
    fn cancel(&self, team: &str, id: &str) -> Option<BakeStatus>;
    /// The status now and every event after it.
    fn subscribe(
        &self,
        team: &str,
        id: &str,
    ) -> Option<(BakeStatus, broadcast::Receiver<BakeEvent>)>;
    /// The bundle bytes that are final while the bake runs (see [`BakeEvent::Sections`]).
    fn bundle_prefix(&self, team: &str, id: &str) -> Option<Arc<Vec<u8>>>;
    /// How often each shape key was used by the team's finished bakes.
    fn shape_uses(&self, team: &str) -> HashMap<String, u64>;
    fn metrics(&self) -> QueueMetrics;
    /// Stops the runner threads after their current bake (running jobs stay `running` on disk
    /// and are queued again at the next start).
    fn shutdown(&self);
}

/// A job as persisted.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct JobRecord {
    pub id: String,
    pub scene: String,
    pub settings: serde_json::Value,
    pub owners: BTreeSet<String>,
    pub state: JobState,
    pub stage: Option<String>,
    pub stage_done: u64,
    pub stage_total: u64,
    pub stages_seen: usize,
    pub expected_stages: usize,
    pub overall: f64,
    pub stages: Vec<StageTiming>,
    pub error: Option<String>,
    pub bundle: Option<String>,
    pub bundle_bytes: Option<u64>,
    pub submitted_at: f64,
    pub finished_at: Option<f64>,
    pub shape_keys: Vec<String>,
    pub inputs: Vec<(BlobKind, String)>,
}

impl serde::Serialize for BlobKind {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> serde::Deserialize<'de> for BlobKind {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<BlobKind, D::Error> {
        let name = String::deserialize(d)?;
        BlobKind::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| serde::de::Error::custom(format!("unknown blob kind {name:?}")))
    }
}

impl JobRecord {
    /// A newly queued job for `request`, visible to `owners` (the submitting team among them),
    /// submitted now.
    pub fn queued(request: &BakeRequest, owners: BTreeSet<String>) -> JobRecord {
        JobRecord {
            id: request.id.clone(),
            scene: request.scene.clone(),
            settings: request.settings.clone(),
            owners,
            state: JobState::Queued,
            stage: None,
            stage_done: 0,
            stage_total: 0,
            stages_seen: 0,
            expected_stages: request.expected_stages.max(1),
            overall: 0.0,
            stages: Vec::new(),
            error: None,
            bundle: None,
            bundle_bytes: None,
            submitted_at: unix_now(),
            finished_at: None,
            shape_keys: Vec::new(),
            inputs: request.inputs.clone(),
        }
    }

    pub fn status(&self, cached: bool) -> BakeStatus {
        BakeStatus {
            id: self.id.clone(),
            scene: self.scene.clone(),
            state: self.state,
            stage: self.stage.clone(),
            stage_done: self.stage_done,
            stage_total: self.stage_total,
            stage_progress: if self.stage_total == 0 {
                0.0
            } else {
                (self.stage_done as f64 / self.stage_total as f64).min(1.0)
            },
            progress: self.overall,
            stages: self.stages.clone(),
            error: self.error.clone(),
            bundle: self.bundle.clone(),
            bundle_bytes: self.bundle_bytes,
            cached,
            submitted_at: self.submitted_at,
            finished_at: self.finished_at,
        }
    }

    pub(super) fn state_event(&self) -> BakeEvent {
        BakeEvent::State {
            state: self.state,
            error: self.error.clone(),
            bundle: self.bundle.clone(),
        }
    }
}

pub(crate) fn unix_now() -> f64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

pub(super) struct Job {
    pub record: JobRecord,
    /// The bundle's leading bytes that are final while the bake runs (not persisted).
    pub prefix: Option<Arc<Vec<u8>>>,
    pub cancel: Arc<AtomicBool>,
    pub events: broadcast::Sender<BakeEvent>,
}

#[derive(Default)]
pub(super) struct Inner {
    pub jobs: HashMap<String, Job>,
    /// Waiting job ids in submission order.
    queue: Vec<String>,
    /// Running bakes per team (for fair picking).
    running_per_team: HashMap<String, usize>,
    stage_seconds: Vec<(String, f64)>,
    finished_seconds: Vec<f64>,
    bake_cache_hits: u64,
    bake_cache_misses: u64,
    shape_cache_hits: u64,
    shape_cache_misses: u64,
    stopping: bool,
}

pub(super) struct Shared {
    pub inner: Mutex<Inner>,
    wake: Condvar,
    dir: PathBuf,
    capacity: usize,
    store: Arc<dyn BlobStore>,
}

impl Shared {
    /// Writes the record (temp file + rename). A failure is logged: the job goes on in memory.
    pub fn persist(&self, record: &JobRecord) {
        let path = self.dir.join(format!("{}.json", record.id));
        let tmp = self.dir.join(format!(".{}.json.tmp", record.id));
        let result = serde_json::to_vec_pretty(record)
            .map_err(std::io::Error::other)
            .and_then(|bytes| fs::write(&tmp, bytes))
            .and_then(|_| fs::rename(&tmp, &path));
        if let Err(e) = result {
            tracing::error!(job = %record.id, "cannot persist job record: {e}");
        }
    }
}

/// The embedded job queue.
pub struct LocalJobs {
    shared: Arc<Shared>,
    threads: Mutex<Vec<std::thread::JoinHandle<()>>>,
}

impl LocalJobs {
    /// Loads the jobs under `dir`, queues again those a previous process left queued or running,
    /// and starts `concurrency` runner threads baking on `pool`.
    pub fn open(
        dir: &Path,
        capacity: usize,
        concurrency: usize,
        pool: Arc<rayon::ThreadPool>,
        store: Arc<dyn BlobStore>,
        executor: Arc<dyn BakeExecutor>,
    ) -> Result<LocalJobs, QueueError> {
        fs::create_dir_all(dir).map_err(|e| QueueError::Io(e.to_string()))?;
        let mut inner = Inner::default();
        let mut requeued: Vec<(f64, String)> = Vec::new();
        for entry in fs::read_dir(dir).map_err(|e| QueueError::Io(e.to_string()))? {
            let path = entry.map_err(|e| QueueError::Io(e.to_string()))?.path();
            if path.extension().and_then(|e| e.to_str()) != Some("json") {
                let _ = fs::remove_file(&path); // a temp file from a write cut short
                continue;
            }
            let record: JobRecord = match fs::read(&path)
                .ok()
                .and_then(|b| serde_json::from_slice(&b).ok())
            {
                Some(r) => r,
                None => {
                    tracing::warn!(path = %path.display(), "unreadable job record: dropped");
                    let _ = fs::remove_file(&path);
                    continue;
                }
            };
            let mut record = record;
            if !record.state.is_final() {
                let was = record.state.name();
                record.state = JobState::Queued;
                record.stage = None;
                record.stage_done = 0;
                record.stage_total = 0;
                record.stages_seen = 0;
                record.overall = 0.0;
                record.error = Some(format!("re-queued after a restart (was {was})"));
                for (kind, hash) in &record.inputs {
                    store.pin(*kind, hash);
                }
                requeued.push((record.submitted_at, record.id.clone()));
            }
            let (events, _) = broadcast::channel(256);
            inner.jobs.insert(
                record.id.clone(),
                Job {
                    record,
                    prefix: None,
                    cancel: Arc::new(AtomicBool::new(false)),
                    events,
                },
            );
        }
        requeued.sort_by(|a, b| a.0.total_cmp(&b.0));
        inner.queue = requeued.into_iter().map(|(_, id)| id).collect();
        let shared = Arc::new(Shared {
            inner: Mutex::new(inner),
            wake: Condvar::new(),
            dir: dir.to_path_buf(),
            capacity,
            store,
        });
        {
            let inner = shared.inner.lock().unwrap();
            for id in &inner.queue {
                shared.persist(&inner.jobs[id].record);
            }
            if !inner.queue.is_empty() {
                tracing::info!(jobs = inner.queue.len(), "re-queued jobs after a restart");
            }
        }
        let threads = (0..concurrency.max(1))
            .map(|i| {
                let shared = shared.clone();
                let pool = pool.clone();
                let executor = executor.clone();
                std::thread::Builder::new()
                    .name(format!("bake-runner-{i}"))
                    .spawn(move || runner(shared, pool, executor))
                    .expect("spawn bake runner")
            })
            .collect();
        Ok(LocalJobs {
            shared,
            threads: Mutex::new(threads),
        })
    }

    /// Seconds until a queue slot is likely free: the mean of recent bake times.
    fn retry_after(inner: &Inner) -> u64 {
        let mean = if inner.finished_seconds.is_empty() {
            5.0
        } else {
            inner.finished_seconds.iter().sum::<f64>() / inner.finished_seconds.len() as f64
        };
        mean.ceil().clamp(1.0, 600.0) as u64
    }
}

/// Picks the next job: the oldest of the team with the fewest running bakes.
fn pick(inner: &mut Inner) -> Option<String> {
    let mut best: Option<(usize, usize)> = None; // (running of team, queue position)
    for (pos, id) in inner.queue.iter().enumerate() {
        let team = inner.jobs[id]
            .record
            .owners
            .iter()
            .next()
            .cloned()
            .unwrap_or_default();
        let running = inner.running_per_team.get(&team).copied().unwrap_or(0);
        if best.is_none_or(|(r, _)| running < r) {
            best = Some((running, pos));
        }
    }
    best.map(|(_, pos)| inner.queue.remove(pos))
}

fn first_owner(record: &JobRecord) -> String {
    record.owners.iter().next().cloned().unwrap_or_default()
}

fn runner(shared: Arc<Shared>, pool: Arc<rayon::ThreadPool>, executor: Arc<dyn BakeExecutor>) {
    loop {
        let (id, scene, settings, cancel, team) = {
            let mut inner = shared.inner.lock().unwrap();
            let id = loop {
                if inner.stopping {
                    return;
                }
                if let Some(id) = pick(&mut inner) {
                    break id;
                }
                inner = shared.wake.wait(inner).unwrap();
            };
            let job = inner.jobs.get_mut(&id).expect("queued job exists");
            job.record.state = JobState::Running;
            job.record.error = None;
            job.record.stages.clear();
            shared.persist(&job.record);
            let _ = job.events.send(job.record.state_event());
            let team = first_owner(&job.record);
            let taken = (
                id.clone(),
                job.record.scene.clone(),
                job.record.settings.clone(),
                job.cancel.clone(),
                team.clone(),
            );
            *inner.running_per_team.entry(team).or_insert(0) += 1;
            taken
        };
        tracing::info!(job = %id, %scene, "bake started");
        let started = Instant::now();
        let progress = JobProgress::new(shared.clone(), id.clone(), cancel.clone());
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            pool.install(|| executor.run(&scene, &settings, &progress))
        }));
        let outcome: Result<BakeOutput, (JobState, String)> = match result {
            Ok(Ok(out)) => Ok(out),
            Ok(Err(message)) => Err((JobState::Failed, message)),
            Err(payload) if payload.is::<Cancelled>() => {
                Err((JobState::Cancelled, "cancelled".to_string()))
            }
            Err(payload) => {
                let message = payload
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_else(|| "unknown panic".into());
                Err((JobState::Failed, format!("internal error: {message}")))
            }
        };
        let stored = outcome.and_then(|out| {
            shared
                .store
                .put(BlobKind::Bundle, &out.bundle)
                .map(|hash| (out, hash))
                .map_err(|e| (JobState::Failed, e.to_string()))
        });
        let seconds = started.elapsed().as_secs_f64();
        let mut inner = shared.inner.lock().unwrap();
        if let Some(n) = inner.running_per_team.get_mut(&team) {
            *n = n.saturating_sub(1);
        }
        let mut finished_stage_seconds = Vec::new();
        let (hits, misses) = {
            let job = inner.jobs.get_mut(&id).expect("running job exists");
            let record = &mut job.record;
            record.finished_at = Some(unix_now());
            let mut counts = (0, 0);
            match stored {
                Ok((out, hash)) => {
                    for owner in &record.owners {
                        if let Err(e) = shared.store.grant(owner, BlobKind::Bundle, &hash) {
                            tracing::error!(job = %id, "cannot grant bundle: {e}");
                        }
                    }
                    record.state = JobState::Succeeded;
                    record.bundle = Some(hash);
                    record.bundle_bytes = Some(out.bundle.len() as u64);
                    record.stages = out
                        .stage_seconds
                        .iter()
                        .map(|(stage, seconds)| StageTiming {
                            stage: stage.clone(),
                            seconds: *seconds,
                        })
                        .collect();
                    record.shape_keys = out.shape_keys;
                    record.overall = 1.0;
                    record.error = None;
                    finished_stage_seconds = out.stage_seconds;
                    counts = (out.shapes_from_cache, out.shapes_computed);
                }
                Err((state, message)) => {
                    record.state = state;
                    record.error = Some(message);
                }
            }
            for (kind, hash) in &record.inputs {
                shared.store.unpin(*kind, hash);
            }
            job.prefix = None;
            cancel.store(false, Ordering::SeqCst);
            shared.persist(record);
            let _ = job.events.send(record.state_event());
            tracing::info!(job = %id, state = record.state.name(), seconds, "bake finished");
            counts
        };
        inner.shape_cache_hits += hits;
        inner.shape_cache_misses += misses;
        if !finished_stage_seconds.is_empty() {
            inner.finished_seconds.push(seconds);
            if inner.finished_seconds.len() > 32 {
                inner.finished_seconds.remove(0);
            }
        }
        for (stage, s) in finished_stage_seconds {
            match inner.stage_seconds.iter_mut().find(|(n, _)| *n == stage) {
                Some((_, total)) => *total += s,
                None => inner.stage_seconds.push((stage, s)),
            }
        }
    }
}

impl JobQueue for LocalJobs {
    fn submit(&self, request: BakeRequest) -> Result<BakeStatus, QueueError> {
        let shared = &self.shared;
        let mut inner = shared.inner.lock().unwrap();
        let queue_full = inner.queue.len() >= shared.capacity;
        let retry_after = Self::retry_after(&inner);
        if let Some(job) = inner.jobs.get_mut(&request.id) {
            let reusable = match job.record.state {
                JobState::Succeeded => job
                    .record
                    .bundle
                    .as_deref()
                    .is_some_and(|h| shared.store.contains(BlobKind::Bundle, h)),
                JobState::Queued | JobState::Running => true,
                JobState::Failed | JobState::Cancelled => false,
            };
            if reusable {
                let new_owner = job.record.owners.insert(request.team.clone());
                let finished = job.record.state == JobState::Succeeded;
                if finished {
                    if let Some(hash) = &job.record.bundle {
                        shared
                            .store
                            .grant(&request.team, BlobKind::Bundle, hash)
                            .map_err(|e| QueueError::Io(e.to_string()))?;
                    }
                }
                if new_owner {
                    shared.persist(&job.record);
                }
                let status = job.record.status(finished);
                if finished {
                    inner.bake_cache_hits += 1;
                }
                return Ok(status);
            }
        }
        if queue_full {
            return Err(QueueError::Full {
                capacity: shared.capacity,
                retry_after,
            });
        }
        for (kind, hash) in &request.inputs {
            shared.store.pin(*kind, hash);
        }
        let mut owners = inner
            .jobs
            .get(&request.id)
            .map(|j| j.record.owners.clone())
            .unwrap_or_default();
        owners.insert(request.team.clone());
        let record = JobRecord::queued(&request, owners);
        shared.persist(&record);
        let status = record.status(false);
        match inner.jobs.get_mut(&request.id) {
            Some(job) => {
                job.record = record;
                job.prefix = None;
                let _ = job.events.send(job.record.state_event());
            }
            None => {
                let (events, _) = broadcast::channel(256);
                inner.jobs.insert(
                    request.id.clone(),
                    Job {
                        record,
                        prefix: None,
                        cancel: Arc::new(AtomicBool::new(false)),
                        events,
                    },
                );
            }
        }
        inner.queue.push(request.id);
        inner.bake_cache_misses += 1;
        drop(inner);
        shared.wake.notify_one();
        Ok(status)
    }

    fn status(&self, team: &str, id: &str) -> Option<BakeStatus> {
        let inner = self.shared.inner.lock().unwrap();
        let job = inner.jobs.get(id)?;
        job.record
            .owners
            .contains(team)
            .then(|| job.record.status(false))
    }

    fn list(&self, team: &str) -> Vec<BakeStatus> {
        let inner = self.shared.inner.lock().unwrap();
        inner
            .jobs
            .values()
            .filter(|job| job.record.owners.contains(team))
            .map(|job| job.record.status(false))
            .collect()
    }

    fn cancel(&self, team: &str, id: &str) -> Option<BakeStatus> {
        let shared = &self.shared;
        let mut inner = shared.inner.lock().unwrap();
        let visible = inner.jobs.get(id)?.record.owners.contains(team);
        if !visible {
            return None;
        }
        let was_queued = inner.jobs[id].record.state == JobState::Queued;
        if was_queued {
            inner.queue.retain(|q| q != id);
        }
        let job = inner.jobs.get_mut(id).expect("checked above");
        match job.record.state {
            JobState::Queued => {
                job.record.state = JobState::Cancelled;
                job.record.error = Some("cancelled".into());
                job.record.finished_at = Some(unix_now());
                for (kind, hash) in &job.record.inputs {
                    shared.store.unpin(*kind, hash);
                }
                shared.persist(&job.record);
                let _ = job.events.send(job.record.state_event());
            }
            JobState::Running => {
                // The runner's progress hook unwinds the bake at its next step.
                job.cancel.store(true, Ordering::SeqCst);
            }
            _ => {}
        }
        Some(job.record.status(false))
    }

    fn subscribe(
        &self,
        team: &str,
        id: &str,
    ) -> Option<(BakeStatus, broadcast::Receiver<BakeEvent>)> {
        let inner = self.shared.inner.lock().unwrap();
        let job = inner.jobs.get(id)?;
        if !job.record.owners.contains(team) {
            return None;
        }
        Some((job.record.status(false), job.events.subscribe()))
    }

    fn bundle_prefix(&self, team: &str, id: &str) -> Option<Arc<Vec<u8>>> {
        let inner = self.shared.inner.lock().unwrap();
        let job = inner.jobs.get(id)?;
        if !job.record.owners.contains(team) {
            return None;
        }
        job.prefix.clone()
    }

    fn shape_uses(&self, team: &str) -> HashMap<String, u64> {
        let inner = self.shared.inner.lock().unwrap();
        let mut uses = HashMap::new();
        for job in inner.jobs.values() {
            if job.record.state == JobState::Succeeded && job.record.owners.contains(team) {
                for key in &job.record.shape_keys {
                    *uses.entry(key.clone()).or_insert(0) += 1;
                }
            }
        }
        uses
    }

    fn metrics(&self) -> QueueMetrics {
        let inner = self.shared.inner.lock().unwrap();
        let by_state = JobState::ALL
            .iter()
            .map(|s| {
                (
                    *s,
                    inner.jobs.values().filter(|j| j.record.state == *s).count() as u64,
                )
            })
            .collect();
        QueueMetrics {
            depth: inner.queue.len() as u64,
            by_state,
            stage_seconds: inner.stage_seconds.clone(),
            bake_cache_hits: inner.bake_cache_hits,
            bake_cache_misses: inner.bake_cache_misses,
            shape_cache_hits: inner.shape_cache_hits,
            shape_cache_misses: inner.shape_cache_misses,
        }
    }

    fn shutdown(&self) {
        self.shared.inner.lock().unwrap().stopping = true;
        self.shared.wake.notify_all();
        // Not joined: a runner finishing a long bake would hold up the exit, and its job is
        // queued again at the next start anyway.
        self.threads.lock().unwrap().clear();
    }
}
