//! lightfarm server: the bake engine ([`bake`]) and the command-line front end ([`cli`]).
//!
//! # Layout
//! - [`bake`]: light transport (no HTTP, no async).
//! - [`cli`]: the `lightfarm` subcommands; `main.rs` only parses arguments and calls these.

pub mod bake;
pub mod cli;
