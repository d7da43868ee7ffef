//! The `lightfarm` subcommands. Each file holds one command; `main.rs` parses arguments with
//! clap and calls `run`. Commands read and write files and print; the math lives in
//! [`crate::bake`] and the client crate.
//!
//! # Layout
//! - [`bake`], [`inspect`], [`eval`] (with [`eval_sh`] and [`lightmap_files`]),
//!   [`reference`](mod@reference), [`compare`], [`frame_time`] (with [`frame_update`]:
//!   `--update one-light`, its probe volume's part [`frame_probes`], [`frame_object`]:
//!   `--update one-object`, and [`frame_moving`]: the
//!   bounce modes while a light moves),
//!   [`export`] (the lit level as glTF): the offline commands.
//! - [`serve`], [`worker`]: the bake service and a farm worker.
//! - [`bench`](mod@bench) (`bench/`): speed against error, its parts listed in its own module doc.
//! - [`progress_bar`]: the terminal progress bar the long commands share.
//!
//! The commands print their reports with [`say!`](crate::say) ([`crate::stdout`]), never
//! `println!`: a reader that has gone (`lightfarm inspect B | head`) is no error.

pub mod bake;
pub mod bench;
pub mod compare;
pub mod eval;
pub mod eval_sh;
pub mod export;
pub mod frame_moving;
pub mod frame_object;
pub mod frame_probes;
pub mod frame_time;
pub mod frame_update;
pub mod inspect;
pub mod lightmap_files;
pub mod progress_bar;
pub mod reference;
pub mod serve;
pub mod worker;

use std::path::Path;

use anyhow::Context;

/// Reads a file to a string, naming it in the error.
pub fn read_text(path: &Path) -> anyhow::Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))
}

/// Writes JSON atomically (temp file + rename).
pub fn write_json(path: &Path, value: &impl serde::Serialize) -> anyhow::Result<()> {
    write_atomic(path, &serde_json::to_vec(value)?)
}

/// Writes bytes to `path` through a temp file in the same directory.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let tmp = dir.join(format!(
        ".{}.tmp{}",
        path.file_name().and_then(|n| n.to_str()).unwrap_or("out"),
        std::process::id()
    ));
    std::fs::write(&tmp, bytes).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}
