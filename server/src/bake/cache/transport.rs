//! On-disk cache of a level's MRT inter-block transport (and its compaction), keyed by what it
//! depends on: the blocks (boxes, open faces, shape keys) and the transport settings. MRT
//! transport ignores clutter, so moving, adding or removing clutter reuses it whole.
//!
//! Layout: `<dir>/transport/<key>.lftransport` = 8-byte FNV-1a checksum of the payload, then the
//! payload (f64 matrices, bit-exact). Written to a temp file and renamed; an entry that fails its
//! checksum or does not decode is deleted and reported as a miss.
//!
//! Invariant: a hit returns exactly what the computation would (the same f64 bits), so a bake
//! is the same bytes with or without the cache.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use faer::Mat;

use lightfarm_proto::scene::{Scene, Transport};
use lightfarm_proto::wire::{checksum, Reader, WireError, Writer};
use lightfarm_proto::Face;

use crate::bake::cache::shape::mark_used;
use crate::bake::transport::build::{MrtTransport, PropBlock, TracedBlock, TransportStats};
use crate::bake::transport::compaction::CompactTransport;

/// Bumped whenever the transport computed for the same inputs changes.
const CODE_VERSION: &str = "lightfarm-transport-1";

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

fn write_mat(w: &mut Writer, m: &Mat<f64>) {
    w.u32(m.nrows() as u32);
    w.u32(m.ncols() as u32);
    for i in 0..m.nrows() {
        for j in 0..m.ncols() {
            w.f64(m[(i, j)]);
        }
    }
}

fn read_mat(r: &mut Reader) -> Result<Mat<f64>, WireError> {
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
    dir: PathBuf,
}

impl TransportCache {
    /// Opens (and creates) `<dir>/transport`.
    pub fn open(dir: &Path) -> std::io::Result<TransportCache> {
        let dir = dir.join("transport");
        fs::create_dir_all(&dir)?;
        Ok(TransportCache { dir })
    }

    fn path(&self, key: &str) -> PathBuf {
        self.dir.join(format!("{key}.lftransport"))
    }

    /// Where the entry with this key lives, relative to the operator cache directory.
    pub fn relative_path(key: &str) -> PathBuf {
        PathBuf::from("transport").join(format!("{key}.lftransport"))
    }

    /// The cached transport, or None (a corrupt entry is deleted).
    pub fn get(&self, key: &str) -> Option<CachedTransport> {
        let path = self.path(key);
        let bytes = fs::read(&path).ok()?;
        let valid = bytes.len() >= 8
            && u64::from_le_bytes(bytes[..8].try_into().unwrap()) == checksum(&bytes[8..]);
        match valid.then(|| decode(&bytes[8..]).ok()).flatten() {
            Some(t) => {
                mark_used(&path);
                Some(t)
            }
            None => {
                let _ = fs::remove_file(&path);
                None
            }
        }
    }

    pub fn put(&self, key: &str, transport: &CachedTransport) -> std::io::Result<()> {
        let payload = encode(transport);
        let tmp = self.dir.join(format!(".{key}.{}.tmp", std::process::id()));
        {
            let mut f = fs::File::create(&tmp)?;
            f.write_all(&checksum(&payload).to_le_bytes())?;
            f.write_all(&payload)?;
            f.sync_all()?;
        }
        fs::rename(&tmp, self.path(key))
    }
}
