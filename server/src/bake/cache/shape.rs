//! On-disk cache of shape operators, keyed by content ([`crate::bake::mrt::shape::ShapeSpec::key`]).
//!
//! Owns the shape entries' kinds and payloads. Each shape is two entries directly in the
//! operator cache directory (the directory [`ShapeCache`] opens and the other caches open
//! theirs under):
//! - [`ENTRY`] (`<dir>/<key>.lfshape`): the operators every bake reads,
//!   [`ShapeOperators::encode`];
//! - [`LIGHTFIELD_ENTRY`] (`<dir>/<key>.lflight`): the openings' lightfields (`OutImp`, `W`),
//!   [`ShapeOperators::encode_lightfields`], which only a transport that is computed reads —
//!   two thirds of a shape's bytes, so a rebake whose transport comes from the cache never
//!   reads them (1.1 GB of shape entries at 1,000 blocks became 0.4 GB).
//!
//! Framing, atomic writes, verification and marking use are [`crate::bake::cache::entry`]'s.
//!
//! Invariant: a hit holds the operators of the key asked for (the payload names its key and
//! [`SHAPE_CODE_VERSION`], both checked; lightfields are checked against their operators'
//! openings and rank), so a bake is the same bytes with or without the cache. A stale entry
//! (older format or version) is a miss; a corrupt one (checksum, length, or the payload does
//! not decode) is deleted and reported as [`Lookup::Corrupt`], then recomputed.
//!
//! [`SHAPE_CODE_VERSION`]: crate::bake::mrt::shape::SHAPE_CODE_VERSION

use std::path::{Path, PathBuf};

use crate::bake::cache::entry::{self, EntryKind, EntryStore};
use crate::bake::mrt::shape::{ShapeLightfields, ShapeOperators};

/// Where shape operator entries live and their version tag (2: the lightfields in entries of
/// their own). The operators' code version is in every key and every payload.
pub const ENTRY: EntryKind = EntryKind {
    subdir: "",
    extension: "lfshape",
    version: "lightfarm-shape-entry-2",
};

/// Where a shape's lightfields live, beside its operators.
pub const LIGHTFIELD_ENTRY: EntryKind = EntryKind {
    subdir: "",
    extension: "lflight",
    version: "lightfarm-shape-lightfields-1",
};

/// A directory of cached shape operators.
#[derive(Clone, Debug)]
pub struct ShapeCache {
    store: EntryStore,
    lightfields: EntryStore,
}

/// What a lookup found.
pub type Lookup = entry::Lookup<Box<ShapeOperators>>;

impl ShapeCache {
    /// Opens (and creates) the cache directory.
    pub fn open(dir: impl Into<PathBuf>) -> std::io::Result<ShapeCache> {
        let dir = dir.into();
        Ok(ShapeCache {
            store: EntryStore::open(dir.clone(), ENTRY)?,
            lightfields: EntryStore::open(dir, LIGHTFIELD_ENTRY)?,
        })
    }

    /// The operator cache directory.
    pub fn dir(&self) -> &Path {
        self.store.dir()
    }

    /// The shape `key` whole: its operators and its openings' lightfields. A hit needs both
    /// entries; either one corrupt is [`Lookup::Corrupt`].
    pub fn get(&self, key: &str) -> Lookup {
        match self.get_operators(key) {
            Lookup::Hit(ops) => match self.get_lightfields(&ops) {
                entry::Lookup::Hit(lightfields) => {
                    Lookup::Hit(Box::new(ops.with_lightfields(lightfields)))
                }
                entry::Lookup::Miss => Lookup::Miss,
                entry::Lookup::Corrupt => Lookup::Corrupt,
            },
            other => other,
        }
    }

    /// The operators of shape `key` alone (every opening's lightfield `None`).
    pub fn get_operators(&self, key: &str) -> Lookup {
        self.store.get(key, |payload| {
            ShapeOperators::decode(payload)
                .ok()
                .filter(|ops| ops.key == key)
                .map(Box::new)
        })
    }

    /// The lightfields of the shape whose operators are `ops`.
    pub fn get_lightfields(&self, ops: &ShapeOperators) -> entry::Lookup<ShapeLightfields> {
        self.lightfields
            .get(&ops.key, |payload| ops.decode_lightfields(payload).ok())
    }

    /// Stores a shape as baked (with its lightfields): the lightfields first, so a reader that
    /// finds the operators finds the lightfields too, unless they were trimmed since.
    pub fn put(&self, ops: &ShapeOperators) -> std::io::Result<()> {
        self.lightfields.put(&ops.key, &ops.encode_lightfields())?;
        self.store.put(&ops.key, &ops.encode())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::math::matrix::narrow;
    use crate::bake::mrt::shape::{OpeningLightfield, OpeningOperators, ShapeStats};
    use faer::Mat;
    use lightfarm_proto::Face;

    fn mat(rows: usize, cols: usize, seed: f64) -> Mat<f64> {
        Mat::from_fn(rows, cols, |i, j| {
            (seed + i as f64 * 0.37 - j as f64 * 0.11).sin()
        })
    }

    /// A hand-made shape of rank 3, 10 texels, two openings (LF 4, q 2).
    fn shape(key: &str) -> ShapeOperators {
        let opening = |face: Face, seed: f64| OpeningOperators {
            face,
            u_r: mat(10, 2, seed),
            pass_from: vec![(Face::ALL[0], vec![(0, 1, 0.5), (3, 2, 0.25)])],
            lightfield: Some(OpeningLightfield {
                out_imp: narrow(&mat(4, 3, seed + 1.0)),
                w: narrow(&mat(2, 4, seed + 2.0)),
            }),
        };
        ShapeOperators {
            key: key.to_string(),
            u_b: mat(10, 3, 0.1),
            t_db: mat(3, 10, 0.2),
            l_imp: mat(10, 3, 0.3),
            openings: vec![opening(Face::ALL[1], 1.0), opening(Face::ALL[4], 2.0)],
            stats: ShapeStats {
                prior_rank: 5,
                rank: 3,
                dropped_energy: 1e-4,
                seconds: 0.5,
            },
        }
    }

    /// The operators and the lightfields come back bit for bit from their own entries; the
    /// operators alone have no lightfield; a whole shape needs both entries, and a corrupt,
    /// missing or foreign lightfield entry is never taken.
    #[test]
    fn operators_and_lightfields_are_entries_of_their_own() {
        let dir = std::env::temp_dir().join(format!("lf-shape-cache-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let cache = ShapeCache::open(&dir).unwrap();
        let a = shape("a");
        cache.put(&a).unwrap();
        let Lookup::Hit(whole) = cache.get("a") else {
            panic!("no hit")
        };
        assert!(whole.encode() == a.encode());
        assert!(whole.encode_lightfields() == a.encode_lightfields());
        let Lookup::Hit(ops) = cache.get_operators("a") else {
            panic!("no hit")
        };
        assert!(ops.openings.iter().all(|o| o.lightfield.is_none()));
        assert!(ops.encode() == a.encode());

        // Another shape's lightfields under this key are refused (and dropped).
        let b = shape("b");
        std::fs::copy(
            dir.join(LIGHTFIELD_ENTRY.relative_path("a")),
            dir.join(LIGHTFIELD_ENTRY.relative_path("b")),
        )
        .unwrap();
        cache.store.put("b", &b.encode()).unwrap();
        assert!(matches!(cache.get("b"), Lookup::Corrupt));

        // A missing lightfield entry: the operators still hit alone, the whole shape misses.
        std::fs::remove_file(dir.join(LIGHTFIELD_ENTRY.relative_path("a"))).unwrap();
        assert!(matches!(cache.get_operators("a"), Lookup::Hit(_)));
        assert!(matches!(cache.get("a"), Lookup::Miss));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
