//! Deferred Neighbouring Radiance Transfer (paper 003): dynamic objects.
//!
//! # Layout
//! - [`grid`]: the transfer grid of one dynamic object, in its own frame.
//!
//! Its on-disk cache is [`crate::bake::cache::dnrt`].

pub mod grid;
