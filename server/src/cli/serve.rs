//! `lightfarm serve`: the bake service on embedded defaults (in-process worker pool, on-disk
//! store under the data directory), or with `--farm` a stateless replica of a bake farm. Builds the tokio runtime here; everything else is in
//! [`crate::service`].

use std::net::SocketAddr;
use std::path::PathBuf;

use crate::service::config::{ServiceConfig, DEFAULT_ADDR, DEFAULT_DATA};

/// Arguments of `lightfarm serve`.
pub struct ServeArgs {
    pub addr: Option<SocketAddr>,
    pub data: Option<PathBuf>,
    pub config: Option<PathBuf>,
    /// `nats://HOST:PORT`: serve as a stateless replica of a bake farm.
    pub farm: Option<String>,
}

/// Runs until SIGINT or SIGTERM.
pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    let mut config = match &args.config {
        Some(path) => ServiceConfig::from_file(path)?,
        None => ServiceConfig::open_local(
            DEFAULT_ADDR.parse().expect("default address"),
            PathBuf::from(DEFAULT_DATA),
        ),
    };
    if let Some(addr) = args.addr {
        config.addr = addr;
    }
    if let Some(data) = args.data {
        config.data = data;
    }
    if let Some(farm) = args.farm {
        config.farm = Some(farm);
    }
    // Before any thread starts: bakes run on the blocking pool and rayon, and per-thread
    // arenas would keep each one's freed memory apart (see `bake::memory`).
    crate::bake::memory::limit_arenas();
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .worker_threads(2)
        .thread_name("http")
        .build()?
        .block_on(crate::service::serve(config))
}
