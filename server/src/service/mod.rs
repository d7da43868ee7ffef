//! The bake service (`lightfarm serve`): an HTTP API over a job queue and a blob store.
//!
//! # Layout
//! - [`config`]: address, data directory, teams and tokens, limits (TOML).
//! - [`store`]: [`store::BlobStore`], content-addressed blobs with per-team visibility;
//!   [`store::DiskStore`] keeps them under the data directory.
//! - [`jobs`]: [`jobs::JobQueue`], bake jobs; [`jobs::LocalJobs`] runs them in this process;
//!   [`job_progress`]: the engine's progress hook per job (events, cancellation);
//!   [`executor`]: one bake from stored scene to stored bundle.
//! - [`scene_inputs`]: API scenes (asset references, settings overrides, limits arithmetic).
//! - [`operator_cache`]: the engine's caches under `<data>/operators`, trimmed
//!   least-recently-used to a byte budget.
//! - [`http`]: routes and handlers; [`farm`]: replicas and workers sharing state through NATS
//!   JetStream (`serve --farm`, `lightfarm worker`).
//!
//! Data directory: `blobs/`, `owners/`, `tmp/` (the store), `jobs/` (job records),
//! `operators/` (the shape-operator and DNRT caches the bake engine keeps), `work/` (scratch).
//!
//! Invariants: handlers reach jobs and blobs only through the two traits, so another backend
//! (a farm) replaces [`jobs::LocalJobs`] and [`store::DiskStore`] without touching them; bake work
//! never runs on the async runtime; the bundle a service bake stores is byte-identical to
//! `lightfarm bake`'s for the same scene and settings.

pub mod config;
pub mod executor;
pub mod farm;
pub mod http;
pub mod job_progress;
pub mod jobs;
pub mod operator_cache;
pub mod scene_inputs;
pub mod store;

use std::net::SocketAddr;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use tokio::sync::watch;

use config::{check_bind, ServiceConfig};
use executor::PipelineExecutor;
use jobs::{JobQueue, LocalJobs};
use store::{BlobStore, DiskStore};

/// A service listening on a socket.
pub struct RunningService {
    pub addr: SocketAddr,
    stop: watch::Sender<bool>,
    server: tokio::task::JoinHandle<std::io::Result<()>>,
    jobs: Arc<dyn JobQueue>,
}

impl RunningService {
    /// Stops accepting, lets running requests finish (SSE streams end), then returns.
    pub async fn shutdown(self) -> std::io::Result<()> {
        let _ = self.stop.send(true);
        let result = self.server.await.unwrap_or(Ok(()));
        self.jobs.shutdown();
        result
    }

    /// Waits until the server stops (after a signal, when started by [`serve`]).
    pub async fn wait(self) -> std::io::Result<()> {
        let result = self.server.await.unwrap_or(Ok(()));
        self.jobs.shutdown();
        result
    }
}

/// Opens the data directory, re-queues unfinished jobs, binds the address and starts serving on
/// the current tokio runtime.
pub async fn start(config: ServiceConfig) -> anyhow::Result<RunningService> {
    check_bind(&config)?;
    let data = config.data.clone();
    std::fs::create_dir_all(&data)
        .map_err(|e| anyhow::anyhow!("data directory {}: {e}", data.display()))?;
    let operator_cache = data.join("operators");
    let (store, jobs) = match &config.farm {
        Some(url) => farm_backend(url, &config).await?,
        None => embedded_backend(&config)?,
    };
    let listener = tokio::net::TcpListener::bind(config.addr).await?;
    let addr = listener.local_addr()?;
    let (stop, stopped) = watch::channel(false);
    let ready = Arc::new(AtomicBool::new(true));
    let state = http::AppState {
        config: Arc::new(config),
        store,
        jobs: jobs.clone(),
        operator_cache,
        ready,
        shutdown: stopped.clone(),
    };
    let app = http::router(state);
    let mut on_stop = stopped;
    let server = tokio::spawn(async move {
        axum::serve(listener, app)
            .with_graceful_shutdown(async move {
                let _ = on_stop.wait_for(|s| *s).await;
            })
            .await
    });
    Ok(RunningService {
        addr,
        stop,
        server,
        jobs,
    })
}

/// The embedded store and job queue under the data directory.
fn embedded_backend(
    config: &ServiceConfig,
) -> anyhow::Result<(Arc<dyn BlobStore>, Arc<dyn JobQueue>)> {
    let data = &config.data;
    let store: Arc<dyn BlobStore> =
        Arc::new(DiskStore::open(data, config.limits.store_budget_bytes)?);
    let threads = match config.limits.worker_threads {
        0 => std::thread::available_parallelism().map_or(2, |n| n.get()),
        n => n,
    };
    let pool = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("bake-worker-{i}"))
            .build()?,
    );
    let executor = Arc::new(PipelineExecutor::new(
        store.clone(),
        &data.join("operators"),
        config.limits.operator_cache_bytes,
        &data.join("work"),
    ));
    let jobs: Arc<dyn JobQueue> = Arc::new(LocalJobs::open(
        &data.join("jobs"),
        config.limits.queue_capacity,
        config.limits.concurrent_bakes,
        pool,
        store.clone(),
        executor,
    )?);
    Ok((store, jobs))
}

/// The farm's store and job queue in NATS JetStream (this process keeps no state).
async fn farm_backend(
    url: &str,
    config: &ServiceConfig,
) -> anyhow::Result<(Arc<dyn BlobStore>, Arc<dyn JobQueue>)> {
    let connection = Arc::new(farm::connection::Farm::connect(url).await?);
    let store = Arc::new(farm::blob_store::FarmStore::new(connection.clone()));
    let jobs: Arc<dyn JobQueue> = Arc::new(farm::queue::FarmJobs::new(
        connection,
        store.clone(),
        config.limits.queue_capacity,
    ));
    Ok((store, jobs))
}

/// Serves until SIGINT or SIGTERM, then shuts down gracefully.
pub async fn serve(config: ServiceConfig) -> anyhow::Result<()> {
    let running = start(config).await?;
    tracing::info!("listening on http://{}", running.addr);
    crate::say!("lightfarm: listening on http://{}", running.addr);
    let stop = running.stop.clone();
    tokio::spawn(async move {
        let ctrl_c = tokio::signal::ctrl_c();
        #[cfg(unix)]
        {
            let mut term =
                tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
                    .expect("SIGTERM handler");
            tokio::select! {
                _ = ctrl_c => {}
                _ = term.recv() => {}
            }
        }
        #[cfg(not(unix))]
        let _ = ctrl_c.await;
        tracing::info!("shutting down: draining requests");
        let _ = stop.send(true);
    });
    running.wait().await?;
    Ok(())
}
