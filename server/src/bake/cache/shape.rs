//! On-disk cache of shape operators, keyed by content ([`crate::bake::mrt::shape::ShapeSpec::key`]).
//!
//! Owns the shape entries' kind ([`ENTRY`]: `<dir>/<key>.lfshape`, directly in the operator cache
//! directory, which is the directory [`ShapeCache`] opens and the other caches open theirs
//! under) and the payload, [`ShapeOperators::encode`]. Framing, atomic writes, verification and
//! marking use are [`crate::bake::cache::entry`]'s.
//!
//! Invariant: a hit holds the operators of the key asked for (the payload names its key and
//! [`SHAPE_CODE_VERSION`], both checked), so a bake is the same bytes with or without the cache.
//! A stale entry (older format or version) is a miss; a corrupt one (checksum, length, or the
//! payload does not decode) is deleted and reported as [`Lookup::Corrupt`], then recomputed.

use std::path::{Path, PathBuf};

use crate::bake::cache::entry::{self, EntryKind, EntryStore};
use crate::bake::mrt::shape::{ShapeOperators, SHAPE_CODE_VERSION};

/// Where shape entries live and their version: the operators' code version, which every shape
/// key also holds.
pub const ENTRY: EntryKind = EntryKind {
    subdir: "",
    extension: "lfshape",
    version: SHAPE_CODE_VERSION,
};

/// A directory of cached shape operators.
#[derive(Clone, Debug)]
pub struct ShapeCache {
    store: EntryStore,
}

/// What a lookup found.
pub type Lookup = entry::Lookup<Box<ShapeOperators>>;

impl ShapeCache {
    /// Opens (and creates) the cache directory.
    pub fn open(dir: impl Into<PathBuf>) -> std::io::Result<ShapeCache> {
        Ok(ShapeCache {
            store: EntryStore::open(dir, ENTRY)?,
        })
    }

    /// The operator cache directory.
    pub fn dir(&self) -> &Path {
        self.store.dir()
    }

    pub fn get(&self, key: &str) -> Lookup {
        self.store.get(key, |payload| {
            ShapeOperators::decode(payload)
                .ok()
                .filter(|ops| ops.key == key)
                .map(Box::new)
        })
    }

    pub fn put(&self, ops: &ShapeOperators) -> std::io::Result<()> {
        self.store.put(&ops.key, &ops.encode())
    }
}
