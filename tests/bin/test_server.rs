//! `lightfarm serve` built as a binary of the tests crate, so that `cargo test` builds it for
//! the end-to-end service tests (`CARGO_BIN_EXE_lightfarm-test-server`) and they can run it as
//! a real process: bind 127.0.0.1:0, SIGKILL it, restart it on the same data directory.
//!
//! Arguments: `--addr HOST:PORT --data DIR [--config FILE] [--farm URL]`, as `lightfarm serve`.
//! It prints `lightfarm: listening on http://ADDR` on stdout once the socket is bound.
//! `worker --farm URL --cache DIR [--threads N] [--cache-bytes B]` runs `lightfarm worker` instead (the farm
//! tests, `tests/farm.rs`), which prints `lightfarm worker NAME: ready` once it pulls work.

use lightfarm_server::cli::serve::{run, ServeArgs};
use lightfarm_server::cli::worker::{run as run_worker, WorkerArgs};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut it = std::env::args().skip(1).peekable();
    if it.peek().map(String::as_str) == Some("worker") {
        it.next();
        let mut args = WorkerArgs {
            farm: String::new(),
            cache: "lightfarm-worker".into(),
            threads: 0,
            cache_bytes: lightfarm_server::service::config::DEFAULT_OPERATOR_CACHE_BYTES,
        };
        while let Some(flag) = it.next() {
            let value = it.next().ok_or_else(|| format!("{flag} needs a value"))?;
            match flag.as_str() {
                "--farm" => args.farm = value,
                "--cache" => args.cache = value.into(),
                "--threads" => args.threads = value.parse()?,
                "--cache-bytes" => args.cache_bytes = value.parse()?,
                other => return Err(format!("unknown argument {other}").into()),
            }
        }
        return run_worker(args).map_err(|e| e.to_string().into());
    }
    let mut args = ServeArgs {
        addr: None,
        data: None,
        config: None,
        farm: None,
    };
    while let Some(flag) = it.next() {
        let value = it.next().ok_or_else(|| format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--addr" => args.addr = Some(value.parse()?),
            "--data" => args.data = Some(value.into()),
            "--config" => args.config = Some(value.into()),
            "--farm" => args.farm = Some(value),
            other => return Err(format!("unknown argument {other}").into()),
        }
    }
    run(args).map_err(|e| e.to_string().into())
}
