//! `lightfarm worker --farm nats://HOST:PORT`: a bake-farm worker. Builds the tokio runtime (the
//! farm client needs a multi-thread one) and runs [`crate::service::farm::worker::run`].

use std::path::PathBuf;

use crate::service::farm::worker::{run as run_worker, WorkerOptions};

/// Arguments of `lightfarm worker`.
pub struct WorkerArgs {
    pub farm: String,
    pub cache: PathBuf,
    pub threads: usize,
    pub cache_bytes: u64,
}

/// Works until killed.
pub fn run(args: WorkerArgs) -> anyhow::Result<()> {
    // As `lightfarm serve`: one malloc arena per core for the bake threads (`bake::memory`).
    crate::bake::memory::limit_arenas();
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .worker_threads(2)
        .thread_name("farm-io")
        .build()?
        .block_on(run_worker(WorkerOptions {
            farm: args.farm,
            cache: args.cache,
            threads: args.threads,
            cache_bytes: args.cache_bytes,
        }))?;
    Ok(())
}
