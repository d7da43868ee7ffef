//! On-disk cache of a level's MRT inter-block transport (and its compaction), keyed by what it
//! depends on: the blocks (boxes, open faces, shape keys) and the transport settings. MRT
//! transport ignores clutter, so moving, adding or removing clutter reuses it whole.
//!
//! Owns the key ([`transport_key`]), the entries' kind ([`ENTRY`]:
//! `<dir>/transport/<key>.lftransport`) and the payload (f64 matrices, bit-exact). Framing,
//! atomic writes, verification and marking use are [`crate::bake::cache::entry`]'s: a stale
//! entry is a miss, a corrupt one (or one that does not decode) is deleted and missed.
//!
//! Invariant: a hit returns exactly what the computation would (the same f64 bits), so a bake
//! is the same bytes with or without the cache.

use std::path::Path;

use faer::Mat;

use lightfarm_proto::scene::{Scene, Transport};
use lightfarm_proto::wire::{Reader, WireError, Writer};
use lightfarm_proto::Face;

use crate::bake::cache::entry::{EntryKind, EntryStore};
use crate::bake::transport::build::{MrtTransport, PropBlock, TracedBlock, TransportStats};
use crate::bake::transport::compaction::CompactTransport;

/// Bumped whenever the transport computed for the same inputs, or its payload, changes (2: the
/// shared entry framing). In every key, and every entry's version tag.
const CODE_VERSION: &str = "lightfarm-transport-2";

/// Where transport entries live and their version.
pub const ENTRY: EntryKind = EntryKind {
    subdir: "transport",
    extension: "lftransport",
    version: CODE_VERSION,
};

/// What the transport stage produces.
pub struct CachedTransport {
    pub mrt: MrtTransport,
    /// Present when the scene ships compact transport.
    pub compact: Option<Vec<CompactTransport>>,
    pub stats: TransportStats,
}

/// The content key of a level's transport: blocks, their shape keys, the transport settings.
pub fn transport_key(scene: &Scene, transport: Transport, shape_keys: &[String]) -> String {
    let s = &scene.settings;
    let mut h = blake3::Hasher::new();
    h.update(CODE_VERSION.as_bytes());
    h.update(&[match transport {
        Transport::Lightfield => 0u8,
        Transport::Traced => 1,
    }]);
    h.update(&[u8::from(s.compact_transport)]);
    h.update(&s.rays_per_texel.to_le_bytes());
    h.update(&s.texels_per_face.to_le_bytes());
    h.update(&s.seed.to_le_bytes());
    h.update(&s.tolerance.to_bits().to_le_bytes());
    for (b, key) in scene.blocks.iter().zip(shape_keys) {
        for x in b.min.iter().chain(&b.max) {
            h.update(&x.to_bits().to_le_bytes());
        }
        for f in b.closed_faces() {
            h.update(&[f.index() as u8]);
        }
        h.update(key.as_bytes());
        h.update(&[0xff]);
    }
    h.finalize().to_hex().to_string()
}

pub(crate) fn write_mat(w: &mut Writer, m: &Mat<f64>) {
    w.u32(m.nrows() as u32);
    w.u32(m.ncols() as u32);
    for i in 0..m.nrows() {
        for j in 0..m.ncols() {
            w.f64(m[(i, j)]);
        }
    }
}

pub(crate) fn read_mat(r: &mut Reader) -> Result<Mat<f64>, WireError> {
    let rows = r.u32()? as usize;
    let cols = r.u32()? as usize;
    if rows.saturating_mul(cols).saturating_mul(8) > r.remaining() {
        return Err(WireError::Invalid("matrix larger than the entry".into()));
    }
    let mut m = Mat::zeros(rows, cols);
    for i in 0..rows {
        for j in 0..cols {
            m[(i, j)] = r.f64()?;
        }
    }
    Ok(m)
}

fn encode(t: &CachedTransport) -> Vec<u8> {
    let mut w = Writer::new();
    match &t.mrt {
        MrtTransport::Lightfield(blocks) => {
            w.u8(0);
            w.u32(blocks.len() as u32);
            for b in blocks {
                w.u32(b.target_block as u32);
                w.u8(b.target_face.index() as u8);
                w.u32(b.source_block as u32);
                write_mat(&mut w, &b.matrix);
            }
        }
        MrtTransport::Traced(blocks) => {
            w.u8(1);
            w.u32(blocks.len() as u32);
            for b in blocks {
                w.u32(b.target_block as u32);
                w.u32(b.source_block as u32);
                write_mat(&mut w, &b.matrix);
            }
        }
    }
    match &t.compact {
        None => w.u8(0),
        Some(entries) => {
            w.u8(1);
            w.u32(entries.len() as u32);
            for c in entries {
                w.u32(c.target_block as u32);
                w.u32s(&c.sources.iter().map(|s| *s as u32).collect::<Vec<_>>());
                write_mat(&mut w, &c.y);
                write_mat(&mut w, &c.z);
                w.f64(c.dropped_energy);
            }
        }
    }
    let s = &t.stats;
    for x in [s.steps, s.cut, s.max_hops, s.pairs_kept, s.pairs_dropped] {
        w.u64(x as u64);
    }
    w.u32s(
        &s.compact_ranks
            .iter()
            .map(|r| *r as u32)
            .collect::<Vec<_>>(),
    );
    w.bytes
}

fn decode(bytes: &[u8]) -> Result<CachedTransport, WireError> {
    let mut r = Reader::new(bytes);
    let kind = r.u8()?;
    let n = r.u32()? as usize;
    let mrt = match kind {
        0 => {
            let mut blocks = Vec::with_capacity(n.min(r.remaining() / 17));
            for _ in 0..n {
                let target_block = r.u32()? as usize;
                let face = r.u8()? as usize;
                let target_face = *Face::ALL
                    .get(face)
                    .ok_or_else(|| WireError::Invalid("face".into()))?;
                blocks.push(PropBlock {
                    target_block,
                    target_face,
                    source_block: r.u32()? as usize,
                    matrix: read_mat(&mut r)?,
                });
            }
            MrtTransport::Lightfield(blocks)
        }
        1 => {
            let mut blocks = Vec::with_capacity(n.min(r.remaining() / 16));
            for _ in 0..n {
                blocks.push(TracedBlock {
                    target_block: r.u32()? as usize,
                    source_block: r.u32()? as usize,
                    matrix: read_mat(&mut r)?,
                });
            }
            MrtTransport::Traced(blocks)
        }
        _ => return Err(WireError::Invalid("transport kind".into())),
    };
    let compact = match r.u8()? {
        0 => None,
        1 => {
            let n = r.u32()? as usize;
            let mut entries = Vec::with_capacity(n.min(r.remaining() / 24));
            for _ in 0..n {
                entries.push(CompactTransport {
                    target_block: r.u32()? as usize,
                    sources: r.u32s()?.into_iter().map(|s| s as usize).collect(),
                    y: read_mat(&mut r)?,
                    z: read_mat(&mut r)?,
                    dropped_energy: r.f64()?,
                });
            }
            Some(entries)
        }
        _ => return Err(WireError::Invalid("compact flag".into())),
    };
    let mut counters = [0usize; 5];
    for c in &mut counters {
        *c = r.u64()? as usize;
    }
    let stats = TransportStats {
        steps: counters[0],
        cut: counters[1],
        max_hops: counters[2],
        pairs_kept: counters[3],
        pairs_dropped: counters[4],
        compact_ranks: r.u32s()?.into_iter().map(|x| x as usize).collect(),
    };
    if r.remaining() != 0 {
        return Err(WireError::Invalid("trailing bytes".into()));
    }
    Ok(CachedTransport {
        mrt,
        compact,
        stats,
    })
}

/// A directory of cached transports.
#[derive(Clone, Debug)]
pub struct TransportCache {
    store: EntryStore,
}

impl TransportCache {
    /// Opens (and creates) `<dir>/transport`.
    pub fn open(dir: &Path) -> std::io::Result<TransportCache> {
        Ok(TransportCache {
            store: EntryStore::open(dir, ENTRY)?,
        })
    }

    /// The cached transport, or None (a corrupt entry is deleted).
    pub fn get(&self, key: &str) -> Option<CachedTransport> {
        self.store.get(key, |payload| decode(payload).ok()).hit()
    }

    pub fn put(&self, key: &str, transport: &CachedTransport) -> std::io::Result<()> {
        self.store.put(key, &encode(transport))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mat(rows: usize, cols: usize, seed: f64) -> Mat<f64> {
        Mat::from_fn(rows, cols, |i, j| (seed + (7 * i + 3 * j) as f64) / 9.0)
    }

    fn stats() -> TransportStats {
        TransportStats {
            steps: 5,
            cut: 1,
            max_hops: 3,
            pairs_kept: 4,
            pairs_dropped: 2,
            compact_ranks: vec![3, 0],
        }
    }

    #[test]
    fn transport_round_trips_bit_exact_through_the_cache() {
        let root = std::env::temp_dir().join(format!("lf-transport-cache-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let cache = TransportCache::open(&root).unwrap();
        let lightfield = CachedTransport {
            mrt: MrtTransport::Lightfield(vec![PropBlock {
                target_block: 1,
                target_face: Face::ALL[4],
                source_block: 0,
                matrix: mat(3, 2, 0.1),
            }]),
            compact: None,
            stats: stats(),
        };
        let traced = CachedTransport {
            mrt: MrtTransport::Traced(vec![TracedBlock {
                target_block: 0,
                source_block: 1,
                matrix: mat(4, 3, 0.2),
            }]),
            compact: Some(vec![CompactTransport {
                target_block: 0,
                sources: vec![0, 1],
                y: mat(4, 2, 0.3),
                z: mat(2, 5, 0.4),
                dropped_energy: 1.0 / 3.0,
            }]),
            stats: stats(),
        };
        assert!(cache.get("k").is_none());
        for t in [lightfield, traced] {
            cache.put("k", &t).unwrap();
            let back = cache.get("k").expect("a hit");
            assert_eq!(encode(&back), encode(&t));
        }
        assert!(root.join(ENTRY.relative_path("k")).is_file());
        // A payload that does not decode (trailing bytes) is corrupt: deleted and missed.
        let mut bytes = encode(&cache.get("k").unwrap());
        bytes.push(0);
        cache.store.put("k", &bytes).unwrap();
        assert!(cache.get("k").is_none());
        assert!(!root.join(ENTRY.relative_path("k")).exists());
        let _ = std::fs::remove_dir_all(&root);
    }
}
