//! The bake engine: light-transport math only.
//!
//! # Layout
//! - [`sampling`]: seeded quasi-random numbers and hemisphere maps.
//! - [`geometry`], [`mesh`], [`mesh_atlas`]: texels and primitives of a scene or a lone shape;
//!   mesh loading; lightmap atlases (texels) of mesh clutter.
//! - [`tracer`]: the obvhs BVH and exact rectangle/triangle intersection.
//! - [`one_bounce`]: sparse one-bounce gather rows (traced transport, the dense operator).
//! - [`lighting_prior`], [`low_rank`], [`lightfield`], [`shape`]: MRT shape operators.
//! - [`shape_cache`]: content-addressed on-disk cache of shape operators.
//! - [`shape_symmetry`]: a block's shape operators from its canonical shape's (rotations and
//!   mirror images).
//! - [`transport`]: inter-block transport (lightfield composition or traced);
//!   [`transport_compaction`]: per target block, the low-rank form the runtime applies;
//!   [`transport_cache`]: the level's transport on disk, keyed by the blocks it depends on.
//! - [`drt`], [`drt_rays`]: Delta Radiance Transfer, its two ray passes and their reuse across
//!   bakes; [`ray_reach`]: the region a texel's rays swept (what a moved object could touch);
//!   [`clutter_basis`]: the basis for direct light on clutter; [`clutter_sampling`]: rays
//!   importance-sampled toward clutter; [`delta_compaction`]: low-rank DRT operators.
//! - [`mesh_albedo`]: per-triangle albedo of mesh clutter (glTF base colour, vertex colours,
//!   textures).
//! - [`reference`]: the brute-force one-bounce reference solver.
//! - [`sh_gather`], [`sh_response`]: SH gathering of implicit radiance (shared with
//!   [`probe_volume`]) and the per-texel SH responses for normal-mapped surfaces.
//! - [`dnrt`], [`dnrt_cache`]: DNRT transfer grids of dynamic objects and their disk cache.
//! - [`pipeline`]: scene → bundle; [`progress`]: how long work reports progress;
//!   [`units`]: a bake cut into deterministic units that fill the operator cache (the farm).
//! - [`bundle_encoding`]: the codecs and compression a bundle is stored with.
//!
//! **Invariant:** nothing here imports axum, tokio or serde_json; everything is deterministic
//! for a given scene and seed, whatever the thread count.

pub mod bundle_encoding;
pub mod clutter_basis;
pub mod clutter_sampling;
pub mod delta_compaction;
pub mod dnrt;
pub mod dnrt_cache;
pub mod drt;
pub mod drt_rays;
pub mod geometry;
pub mod lightfield;
pub mod lighting_prior;
pub mod low_rank;
pub mod mesh;
pub mod mesh_albedo;
pub mod mesh_atlas;
pub mod one_bounce;
pub mod pipeline;
pub mod probe_volume;
pub mod progress;
pub mod ray_reach;
pub mod reference;
pub mod sampling;
pub mod sh_gather;
pub mod sh_response;
pub mod shape;
pub mod shape_cache;
pub mod shape_symmetry;
pub mod tracer;
pub mod transport;
pub mod transport_cache;
pub mod transport_compaction;
pub mod units;
