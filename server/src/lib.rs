//! lightfarm server: the bake engine ([`bake`]), the bake service ([`service`]) and the
//! command-line front end ([`cli`]).
//!
//! # Layout
//! - [`bake`]: light transport (no HTTP, no async).
//! - [`service`]: `lightfarm serve`, the HTTP API over a job queue and a blob store (no light
//!   transport: it calls [`bake::bake()`]).
//! - [`cli`]: the `lightfarm` subcommands; `main.rs` only parses arguments and calls these.
//! - [`evaluate`]: a bundle applied to a light set through the client (the `eval` command,
//!   the bench and the service's evaluate endpoint share it); no HTTP, no file I/O.
//! - [`export`]: the lit level as glTF (`lightfarm export`, the service's preview); no HTTP.
//! - [`stdout`]: [`say!`], the `println!` of the commands and the service that survives a
//!   reader that has gone.

pub mod bake;
pub mod cli;
pub mod evaluate;
pub mod export;
pub mod service;
pub mod stdout;
