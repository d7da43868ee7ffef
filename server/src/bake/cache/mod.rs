//! On-disk caches of bake stages, keyed by content, so a rebake redoes only what changed.
//!
//! # Layout
//! - [`shape`]: shape operators (MRT), keyed by shape and settings.
//! - [`transport`]: a level's inter-block transport and its compaction.
//! - [`dnrt`]: DNRT grids of dynamic objects.
//!
//! (DRT's ray cache lives with the rays, in [`crate::bake::drt::rays`].)

pub mod dnrt;
pub mod shape;
pub mod transport;
