//! On-disk caches of bake stages, keyed by content, so a rebake redoes only what changed. They
//! hold intermediate results only: a bake is the same bytes with or without them.
//!
//! # Layout
//! - [`entry`]: the one entry format and store every cache uses — naming
//!   (`<dir>/<subdir>/<key>.<ext>`), version tag, checksum framing, atomic writes, verification
//!   (stale: a miss; corrupt: deleted and a miss) and marking use for LRU trimming.
//! - [`shape`]: shape operators (MRT), keyed by shape and settings (`<dir>/<key>.lfshape`, and the openings' lightfields beside them in `<key>.lflight`).
//! - [`transport`]: a level's inter-block transport and its compaction (`transport/`): a main
//!   entry read on a hit, and each target block's f64 operators read only when asked for.
//! - [`dnrt`]: DNRT grids of dynamic objects (`dnrt/`).
//! - [`drt_rays`]: DRT ray-pass units and clutter prior bases (`drt/`), keyed and reused by
//!   [`crate::bake::drt::rays`].
//! - [`factors`]: the DRT compaction's truncated SVDs (`factors/`), keyed by the matrix.
//! - [`encodings`]: the bundle writer's matrix encodings of a level's last write
//!   (`encodings/`), handed back for the matrices a rebake writes unchanged.
//! - [`bundle_memo`]: whole encoded bundles (`bundles/`), keyed by everything a bake reads
//!   (the engine's build, the scene, the options, the mesh files), so a rebake with nothing
//!   changed costs a lookup.
//!
//! Each cache owns its key and payload serialization; `<dir>` is the operator cache directory
//! [`shape::ShapeCache`] opens.

pub mod bundle_memo;
pub mod dnrt;
pub mod drt_rays;
pub mod encodings;
pub mod entry;
pub mod factors;
pub mod shape;
pub mod transport;
