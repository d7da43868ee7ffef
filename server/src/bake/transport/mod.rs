//! Inter-block transport (MRT §3.3): how light leaving one block reaches the others.
//!
//! # Layout
//! - [`build`]: transport traced per target block through its openings (the default), or by
//!   lightfield composition.
//! - [`compaction`]: per target block, the low-rank form the runtime applies (ours).
//! - [`source_bases`]: per source block, a row basis shared by its receivers (bundle
//!   transport kind 3, ours).
//! - [`flux`]: the compact transport turned so that one row of each stored factor carries
//!   the flux it delivers (ours).
//! - [`source`]: where DRT's inpainting reads the transport into a few blocks (held, or
//!   read from the cache block by block).
//!
//! Its on-disk cache is [`crate::bake::cache::transport`].

pub mod build;
pub mod compaction;
pub mod flux;
pub mod source;
pub mod source_bases;
