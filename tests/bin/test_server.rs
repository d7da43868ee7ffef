//! `lightfarm serve` built as a binary of the tests crate, so that `cargo test` builds it for
//! the end-to-end service tests (`CARGO_BIN_EXE_lightfarm-test-server`) and they can run it as
//! a real process: bind 127.0.0.1:0, SIGKILL it, restart it on the same data directory.
//!
//! Arguments: `--addr HOST:PORT --data DIR [--config FILE]`, as `lightfarm serve`. It prints
//! `lightfarm: listening on http://ADDR` on stdout once the socket is bound.

use lightfarm_server::cli::serve::{run, ServeArgs};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = ServeArgs {
        addr: None,
        data: None,
        config: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let value = it.next().ok_or_else(|| format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--addr" => args.addr = Some(value.parse()?),
            "--data" => args.data = Some(value.into()),
            "--config" => args.config = Some(value.into()),
            other => return Err(format!("unknown argument {other}").into()),
        }
    }
    run(args).map_err(|e| e.to_string().into())
}
