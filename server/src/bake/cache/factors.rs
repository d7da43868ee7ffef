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
        let mut h = key_header(tolerance, max_values, m.nrows(), m.ncols());
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

    /// The key of factoring a `rows × cols` matrix that `describe` determines bit for bit (it
    /// feeds the hasher a description the matrix is a pure function of, e.g. its nonzeros in
    /// the order they are summed), described the `tag` way: a key apart from [`Self::key`]'s
    /// and from other tags', which costs the description instead of every value.
    pub fn key_described(
        tag: &str,
        tolerance: f64,
        max_values: usize,
        (rows, cols): (usize, usize),
        describe: impl FnOnce(&mut blake3::Hasher),
    ) -> String {
        let mut h = key_header(tolerance, max_values, rows, cols);
        h.update(b"described:");
        h.update(&(tag.len() as u64).to_le_bytes());
        h.update(tag.as_bytes());
        describe(&mut h);
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

/// What every key starts with: the version, the tolerance, a bound on the factors' size (entries
/// without one keep the keys they always had) and the matrix's size.
fn key_header(tolerance: f64, max_values: usize, rows: usize, cols: usize) -> blake3::Hasher {
    let mut h = blake3::Hasher::new();
    h.update(CODE_VERSION.as_bytes());
    h.update(&tolerance.to_bits().to_le_bytes());
    if max_values != usize::MAX {
        h.update(b"max_values");
        h.update(&(max_values as u64).to_le_bytes());
    }
    h.update(&(rows as u64).to_le_bytes());
    h.update(&(cols as u64).to_le_bytes());
    h
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

    /// A described key follows the description, the tag, the size and the tolerance, and never
    /// equals a dense key, even for a description that is the dense key's own bytes.
    #[test]
    fn described_keys_follow_what_describes_the_matrix() {
        let m = Mat::from_fn(3, 2, |i, j| (i * 2 + j) as f64);
        let bits: Vec<u8> = (0..2)
            .flat_map(|j| (0..3).flat_map(move |i| ((i * 2 + j) as f64).to_bits().to_le_bytes()))
            .collect();
        let key = |tag: &str, tol: f64, size: (usize, usize), bytes: &[u8]| {
            FactorCache::key_described(tag, tol, usize::MAX, size, |h| {
                h.update(bytes);
            })
        };
        let k = key("a", 1e-3, (3, 2), &bits);
        assert_eq!(k, key("a", 1e-3, (3, 2), &bits));
        assert_ne!(k, FactorCache::key(&m, 1e-3, usize::MAX));
        assert_ne!(k, key("b", 1e-3, (3, 2), &bits));
        assert_ne!(k, key("a", 2e-3, (3, 2), &bits));
        assert_ne!(k, key("a", 1e-3, (2, 3), &bits));
        assert_ne!(k, key("a", 1e-3, (3, 2), &bits[1..]));
        // The tag's length is hashed: a tag cannot run on into the description.
        assert_ne!(key("ab", 1e-3, (3, 2), b"c"), key("a", 1e-3, (3, 2), b"bc"));
    }
}
