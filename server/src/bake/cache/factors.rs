//! On-disk cache of the DRT compaction's truncated SVDs, keyed by the matrix factored (every
//! f64 bit), its shape and the tolerance: a rebake after a small change refactors only the
//! delta entries and gather ranges the change touched (issue 19). Factoring is most of a
//! rebake's time once the rays are cached.
//!
//! Owns the key ([`FactorCache::key`]), the entries' kind ([`ENTRY`]:
//! `<dir>/factors/<key>.lffactor`) and the payload: a flag, then `left` and `mix` (f64,
//! bit-exact) when the matrix was factored. An outcome of "kept dense" is stored too (the SVD
//! that decided it is the cost). Framing, atomic writes, verification and marking use are
//! [`crate::bake::cache::entry`]'s.
//!
//! Invariant: a hit returns exactly what factoring computes (the same f64 bits, the same
//! decision), so a bake is the same bytes with or without the cache. Matrices smaller than
//! [`MIN_VALUES`] are not cached (factoring them costs less than a file).

use std::path::Path;

use faer::Mat;

use lightfarm_proto::wire::{Reader, Writer};

use crate::bake::cache::entry::{EntryKind, EntryStore};
use crate::bake::cache::transport::{read_mat, write_mat};

/// Bumped whenever what factoring computes for the same matrix, or the payload, changes.
const CODE_VERSION: &str = "lightfarm-factors-1";

/// Where factor entries live and their version.
pub const ENTRY: EntryKind = EntryKind {
    subdir: "factors",
    extension: "lffactor",
    version: CODE_VERSION,
};

/// Matrices with fewer values than this are factored without the cache.
pub const MIN_VALUES: usize = 4096;

/// A factoring's outcome: `(left, mix)`, or None when the matrix stays dense.
pub type Factors = Option<(Mat<f64>, Mat<f64>)>;

/// The factor cache in an operator cache directory.
#[derive(Clone, Debug)]
pub struct FactorCache {
    store: EntryStore,
}

impl FactorCache {
    /// Opens (and creates) `<dir>/factors`.
    pub fn open(dir: &Path) -> std::io::Result<FactorCache> {
        Ok(FactorCache {
            store: EntryStore::open(dir, ENTRY)?,
        })
    }

    /// The key of factoring `m` at `tolerance` into factors of at most `max_values` values
    /// (`usize::MAX`: no bound beyond the compaction's own).
    pub fn key(m: &Mat<f64>, tolerance: f64, max_values: usize) -> String {
        let mut h = blake3::Hasher::new();
        h.update(CODE_VERSION.as_bytes());
        h.update(&tolerance.to_bits().to_le_bytes());
        // A bound on the factors' size changes the outcome; entries without one keep the
        // keys they always had.
        if max_values != usize::MAX {
            h.update(b"max_values");
            h.update(&(max_values as u64).to_le_bytes());
        }
        h.update(&(m.nrows() as u64).to_le_bytes());
        h.update(&(m.ncols() as u64).to_le_bytes());
        let mut column = Vec::with_capacity(m.nrows() * 8);
        for j in 0..m.ncols() {
            column.clear();
            for i in 0..m.nrows() {
                column.extend_from_slice(&m[(i, j)].to_bits().to_le_bytes());
            }
            h.update(&column);
        }
        h.finalize().to_hex().to_string()
    }

    /// The stored outcome of key `key`, if any.
    pub fn get(&self, key: &str) -> Option<Factors> {
        self.store
            .get(key, |payload| {
                let mut r = Reader::new(payload);
                let factors = match r.u8().ok()? {
                    0 => None,
                    1 => Some((read_mat(&mut r).ok()?, read_mat(&mut r).ok()?)),
                    _ => return None,
                };
                (r.remaining() == 0).then_some(factors)
            })
            .hit()
    }

    /// Stores the outcome `factors` as entry `key`.
    pub fn put(&self, key: &str, factors: &Factors) -> std::io::Result<()> {
        let mut w = Writer::new();
        match factors {
            None => w.u8(0),
            Some((left, mix)) => {
                w.u8(1);
                write_mat(&mut w, left);
                write_mat(&mut w, mix);
            }
        }
        self.store.put(key, &w.bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outcomes_come_back_bit_for_bit_and_keys_follow_every_bit() {
        let root = std::env::temp_dir().join(format!("lf-factors-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let cache = FactorCache::open(&root).unwrap();
        let m = Mat::from_fn(70, 60, |i, j| ((i * 7 + j * 3) as f64).sin() * 1e-3);
        let k = FactorCache::key(&m, 1e-3, usize::MAX);
        assert_eq!(cache.get(&k), None);
        let factors = Some((
            Mat::from_fn(70, 2, |i, j| (i + j) as f64 / 3.0),
            Mat::from_fn(2, 60, |i, j| {
                f64::from_bits(((i * 60 + j) as u64) | 0x3ff0_0000_0000_0001)
            }),
        ));
        cache.put(&k, &factors).unwrap();
        assert_eq!(cache.get(&k), Some(factors));
        let dense = FactorCache::key(&m, 2e-3, usize::MAX);
        cache.put(&dense, &None).unwrap();
        assert_eq!(cache.get(&dense), Some(None));
        // One bit of one value, or the tolerance, is another key.
        let mut m2 = m.clone();
        m2[(69, 59)] = f64::from_bits(m2[(69, 59)].to_bits() ^ 1);
        assert_ne!(FactorCache::key(&m2, 1e-3, usize::MAX), k);
        // So is a bound on the factors' size.
        assert_ne!(FactorCache::key(&m, 1e-3, 5000), k);
        assert_ne!(
            FactorCache::key(&m, 1e-3, 5000),
            FactorCache::key(&m, 1e-3, 5001)
        );
        assert_ne!(dense, k);
        let _ = std::fs::remove_dir_all(&root);
    }
}
