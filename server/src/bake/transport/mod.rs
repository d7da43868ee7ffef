//! Inter-block transport (MRT §3.3): how light leaving one block reaches the others.
//!
//! # Layout
//! - [`build`]: transport by lightfield composition through the openings, or traced.
//! - [`compaction`]: per target block, the low-rank form the runtime applies (ours).
//!
//! Its on-disk cache is [`crate::bake::cache::transport`].

pub mod build;
pub mod compaction;
