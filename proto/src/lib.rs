//! The lightfarm contract: what crosses a crate or process boundary.
//!
//! # Layout
//! - [`api`]: the bake service's HTTP API types (`/v1`).
//! - [`scene`]: the scene description `lightfarm.scene/1`, its validation and JSON Schema.
//! - [`lights`]: LIGHTS.json (point lights, dynamic-object poses).
//! - [`bounces`]: how many bounces of indirect light a result sums (`--bounces N|all`).
//! - [`result`]: RESULT.json (per-texel direct and indirect radiance) and `compare`.
//! - [`bundle`]: the operator bundle the server writes and the client reads (a folder: the
//!   types in `bundle/mod.rs`, then one file per concept: section kinds, writing, reading, the
//!   reading of 1.x bundles, and each section encoding of its own, e.g. `bundle/sh_responses.rs`
//!   for the SH responses section of normal-mapped surfaces, minor 2).
//!   [`container`]: its header, compressed and checksummed sections and table of contents;
//!   [`codec`]: how one operator matrix's values are stored (a folder: quantizing, prediction,
//!   the choice by error budget, writing and reading).
//! - [`box_symmetry`]: the 48 symmetries of an axis-aligned box and how they map faces and
//!   face grids onto a canonical shape's.
//! - [`face`]: box faces and the texel layout on each (`tangent_axes`, shared by every crate).
//! - [`wire`]: the little-endian encoding the bundle and the operator cache share.
//! - [`range_coder`]: an adaptive binary range coder (LZMA's) and its models, for the bundle
//!   sections whose symbols a context predicts better than zstd's order-0 Huffman codes them.
//! - [`dnrt_grid`]: one dynamic object's DNRT transfer grid (codecs, ranges, placement).
//! - [`sh`], [`sh_rotation`]: the SH convention and rotation of SH coefficients.
//! - [`work_queue`]: the bundle writer's parallel map (jobs in order on scoped threads).
//! - `glam`: the vector crate, re-exported, so the client (which depends on this crate only)
//!   writes its f32 geometry (`Vec3`) with the same types the server uses.
//! - `testing` (feature `testing`, tests only): seeded hand-built bundles for the decoder
//!   fuzzing here and the client runtime's tests.
//!
//! Invariant: this crate does no light-transport math and no I/O beyond bytes and strings.

pub use glam;

pub mod api;
pub mod bounces;
pub mod box_symmetry;
pub mod bundle;
pub mod codec;
pub mod container;
pub mod dnrt_grid;
pub mod face;
pub mod lights;
pub mod range_coder;
pub mod result;
pub mod scene;
pub mod sh;
pub mod sh_rotation;
#[cfg(feature = "testing")]
pub mod testing;
pub mod wire;
pub mod work_queue;

pub use face::Face;
