//! On-disk cache of shape operators, keyed by content ([`crate::bake::mrt::shape::ShapeSpec::key`]).
//!
//! Layout: `<dir>/<key>.lfshape` = 8-byte FNV-1a checksum of the payload, then the payload
//! ([`ShapeOperators::encode`]). Writes go to a temp file in the same directory and are renamed
//! into place, so a crash never leaves a half-written entry under a real key. An entry that fails
//! its checksum or does not decode is deleted and reported as a miss, so it is recomputed.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use lightfarm_proto::wire::checksum;

use crate::bake::mrt::shape::ShapeOperators;

/// Marks a cache file as just used (its modification time), for least-recently-used trimming
/// by whoever bounds the cache's size. Best effort: a failure only makes the entry look older.
pub fn mark_used(path: &Path) {
    if let Ok(f) = fs::File::options().append(true).open(path) {
        let _ = f.set_modified(std::time::SystemTime::now());
    }
}

/// A directory of cached shape operators.
#[derive(Clone, Debug)]
pub struct ShapeCache {
    dir: PathBuf,
}

/// What a lookup found.
#[derive(Debug)]
pub enum Lookup {
    Hit(Box<ShapeOperators>),
    Miss,
    /// An entry was there but corrupt; it has been removed.
    Corrupt,
}

impl ShapeCache {
    /// Opens (and creates) the cache directory.
    pub fn open(dir: impl Into<PathBuf>) -> std::io::Result<ShapeCache> {
        let dir = dir.into();
        fs::create_dir_all(&dir)?;
        Ok(ShapeCache { dir })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn path(&self, key: &str) -> PathBuf {
        self.dir.join(format!("{key}.lfshape"))
    }

    pub fn get(&self, key: &str) -> Lookup {
        let path = self.path(key);
        let Ok(bytes) = fs::read(&path) else {
            return Lookup::Miss;
        };
        let valid = bytes.len() >= 8 && {
            let stored = u64::from_le_bytes(bytes[..8].try_into().unwrap());
            stored == checksum(&bytes[8..])
        };
        if valid {
            if let Ok(ops) = ShapeOperators::decode(&bytes[8..]) {
                if ops.key == key {
                    mark_used(&path);
                    return Lookup::Hit(Box::new(ops));
                }
            }
        }
        let _ = fs::remove_file(&path);
        Lookup::Corrupt
    }

    pub fn put(&self, ops: &ShapeOperators) -> std::io::Result<()> {
        let payload = ops.encode();
        let tmp = self
            .dir
            .join(format!(".{}.{}.tmp", ops.key, std::process::id()));
        {
            let mut f = fs::File::create(&tmp)?;
            f.write_all(&checksum(&payload).to_le_bytes())?;
            f.write_all(&payload)?;
            f.sync_all()?;
        }
        fs::rename(&tmp, self.path(&ops.key))
    }
}
