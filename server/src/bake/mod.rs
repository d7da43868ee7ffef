//! The bake engine: light-transport math only.
//!
//! # Layout (in data-flow order: scene → operators → bundle)
//! - [`math`]: seeded sampling and the registry of random streams; truncated SVD.
//! - [`scene`]: texels and primitives of a scene or a lone shape; meshes, their albedo and
//!   lightmap atlases.
//! - [`tracer`]: an 8-wide BVH (from obvhs's BVH2), exact rectangle/triangle intersection and
//!   the f32 triangle test four at a time.
//! - [`mrt`]: scene-independent shape operators (lighting prior, lightfields, shapes and their
//!   symmetries) and the one-bounce gather rows.
//! - [`transport`]: inter-block transport and its per-block compaction.
//! - [`drt`]: Delta Radiance Transfer for clutter (basis, sampling, ray passes, deltas,
//!   compaction).
//! - [`dnrt`]: DNRT transfer grids of dynamic objects.
//! - [`sh`]: SH gathering, the probe volume `U_dyn` and SH responses for normal maps.
//! - [`cache`]: the on-disk caches of shapes, transport, DRT ray units and DNRT grids, all in
//!   one entry format.
//! - [`pipeline`]: scene → bundle, stage by stage, and the codecs a bundle is stored with;
//!   [`bake()`], [`BakeOptions`], [`BakeReport`] and [`BakeError`] are its facade, re-exported
//!   here. [`units`]: a bake cut into deterministic cache-filling units (the farm).
//! - [`reference`](mod@reference): the brute-force path-tracing reference; [`progress`]: how long work reports
//!   progress; [`memory`]: a finished stage's freed memory handed back to the OS.
//!
//! **Invariant:** nothing here imports axum, tokio or serde_json; everything is deterministic
//! for a given scene and seed, whatever the thread count.

pub mod cache;
pub mod dnrt;
pub mod drt;
pub mod math;
pub mod memory;
pub mod mrt;
pub mod pipeline;
pub mod progress;
pub mod reference;
pub mod scene;
pub mod sh;
pub mod tracer;
pub mod transport;
pub mod units;

pub use pipeline::{bake, BakeError, BakeOptions, BakeReport};
