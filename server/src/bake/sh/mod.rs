//! Spherical-harmonic light: probes for dynamic objects and responses for normal maps.
//!
//! # Layout
//! - [`gather`]: SH gathering of the runtime's implicit radiance along rays (shared).
//! - [`probe_volume`]: `U_dyn`, the grid of SH radiance probes over the blocks.
//! - [`responses`]: per-texel SH responses for normal-mapped surfaces.

pub mod gather;
pub mod probe_volume;
pub mod responses;
