//! On-disk cache of a level's MRT inter-block transport (and its compaction), keyed by what it
//! depends on: the blocks (boxes, open faces, shape keys) and the transport settings. MRT
//! transport ignores clutter, so moving, adding or removing clutter reuses it whole.
//!
//! Owns the key ([`transport_key`]), the entries' kind ([`ENTRY`]) and the payloads (matrices
//! bit-exact: the lightfield `T_prop` in f32 as the bake holds it, traced operators in f64), in
//! two parts:
//! - the main entry `<dir>/transport/<key>.lftransport`: every operator's header (target block,
//!   target face, source block) in transport order, the compaction (f32, as the bundle ships
//!   it) and the statistics: what a hit reads ([`TransportCache::get`]);
//! - per target block `<key>.t<block>.lftransport`: that block's operators' matrices in header
//!   order, read only when asked for ([`LazyTransport`], a
//!   [`crate::bake::transport::source::TransportSource`]): DRT's inpainting needs the blocks
//!   holding a buried texel, one at a time, where the whole is 0.8 GB at 1,000 blocks. A bake
//!   writes them as its compaction consumes the transport ([`TransportWriter`]), so it never
//!   holds the whole.
//!
//! Framing, atomic writes, verification and marking use are [`crate::bake::cache::entry`]'s: a
//! stale entry is a miss, a corrupt one (or one that does not decode) is deleted and missed; a
//! target block's entry that cannot be read when asked for also deletes the main entry, so the
//! next bake computes the transport (and [`crate::bake::bake`] bakes once more at once).
//!
//! Invariant: a hit returns exactly what the computation would (the same bits), so a bake is
//! the same bytes with or without the cache.

use std::collections::BTreeMap;
use std::path::Path;

use faer::Mat;

use lightfarm_proto::bundle::{CompactEntry, Matrix, SourceBases, SourceBasis};

use lightfarm_proto::scene::{Scene, Transport};
use lightfarm_proto::wire::{Reader, WireError, Writer};
use lightfarm_proto::Face;

use crate::bake::cache::entry::{EntryKind, EntryStore};
use crate::bake::transport::build::{MrtTransport, PropBlock, TracedBlock, TransportStats};
use crate::bake::transport::source::{TransportSource, TransportUnavailable};
use crate::bake::transport::source_bases::FactoringStats;

/// Bumped whenever the transport computed for the same inputs, or its payload, changes (2: the
/// shared entry framing; 3: each target block's operators an entry of their own; 4: the
/// compaction in f32, as the bundle ships it; 5: the lightfield `T_prop` in f32, as the bake holds
/// it; 6: the compaction with its sources' shared bases, and their statistics; 7: the
/// compaction turned so that one row carries the flux, `transport::flux`). In every key, and
/// every entry's version tag.
const CODE_VERSION: &str = "lightfarm-transport-7";

/// Where transport entries live and their version.
pub const ENTRY: EntryKind = EntryKind {
    subdir: "transport",
    extension: "lftransport",
    version: CODE_VERSION,
};

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

/// A value a cached matrix holds: f64, or f32 where the bake holds it so (the lightfield
/// `T_prop`), stored bit-exact little-endian.
pub(crate) trait CachedValue: Copy + 'static {
    const BYTES: usize;
    fn write(self, w: &mut Writer);
    fn from_le(bytes: &[u8]) -> Self;
}

impl CachedValue for f64 {
    const BYTES: usize = 8;
    fn write(self, w: &mut Writer) {
        w.f64(self);
    }
    fn from_le(bytes: &[u8]) -> f64 {
        f64::from_le_bytes(bytes.try_into().expect("8 bytes"))
    }
}

impl CachedValue for f32 {
    const BYTES: usize = 4;
    fn write(self, w: &mut Writer) {
        w.f32(self);
    }
    fn from_le(bytes: &[u8]) -> f32 {
        f32::from_le_bytes(bytes.try_into().expect("4 bytes"))
    }
}

/// A matrix as its dimensions (u32 rows, cols) and its values row by row (bit-exact).
pub(crate) fn write_mat<T: CachedValue>(w: &mut Writer, m: &Mat<T>) {
    w.u32(m.nrows() as u32);
    w.u32(m.ncols() as u32);
    w.bytes.reserve(m.nrows() * m.ncols() * T::BYTES);
    for i in 0..m.nrows() {
        for j in 0..m.ncols() {
            m[(i, j)].write(w);
        }
    }
}

/// What [`write_mat`] wrote: the values taken as one slice and placed column by column (the
/// matrix's own order), without a check per value.
pub(crate) fn read_mat<T: CachedValue>(r: &mut Reader) -> Result<Mat<T>, WireError> {
    let rows = r.u32()? as usize;
    let cols = r.u32()? as usize;
    let len = rows
        .checked_mul(cols)
        .and_then(|n| n.checked_mul(T::BYTES))
        .filter(|&n| n <= r.remaining())
        .ok_or_else(|| WireError::Invalid("matrix larger than the entry".into()))?;
    let bytes = r.take(len)?;
    let value = |k: usize| T::from_le(&bytes[T::BYTES * k..T::BYTES * (k + 1)]);
    Ok(Mat::from_fn(rows, cols, |i, j| value(i * cols + j)))
}

/// An f32 matrix of the compaction (as the bundle ships it): rows, cols, values row-major.
fn write_matrix(w: &mut Writer, m: &Matrix) {
    w.u32(m.rows);
    w.u32(m.cols);
    w.f32s(&m.data);
}

fn read_matrix(r: &mut Reader) -> Result<Matrix, WireError> {
    let (rows, cols) = (r.u32()?, r.u32()?);
    let data = r.f32s()?;
    if data.len() as u64 != rows as u64 * cols as u64 {
        return Err(WireError::Invalid("matrix size".into()));
    }
    Ok(Matrix { rows, cols, data })
}

/// Per transport operator, in transport order: its target block, its target face (lightfield;
/// `None` traced) and its source block. The main entry lists these; each target block's
/// matrices are an entry of their own, in this order.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Header {
    target: usize,
    face: Option<Face>,
    source: usize,
}

/// How many operators `mrt` holds.
fn headers_len(mrt: &MrtTransport) -> usize {
    match mrt {
        MrtTransport::Lightfield(blocks) => blocks.len(),
        MrtTransport::Traced(blocks) => blocks.len(),
    }
}

fn headers(mrt: &MrtTransport) -> Vec<Header> {
    match mrt {
        MrtTransport::Lightfield(blocks) => blocks
            .iter()
            .map(|b| Header {
                target: b.target_block,
                face: Some(b.target_face),
                source: b.source_block,
            })
            .collect(),
        MrtTransport::Traced(blocks) => blocks
            .iter()
            .map(|b| Header {
                target: b.target_block,
                face: None,
                source: b.source_block,
            })
            .collect(),
    }
}

/// The matrices of `mrt`'s operators `indices` (positions in transport order), written as
/// [`write_mat`] writes them (the lightfield's `T_prop` in f32, traced operators in f64): one
/// target's entry is the writes of its operators back to back.
fn write_matrices(w: &mut Writer, mrt: &MrtTransport, indices: impl Iterator<Item = usize>) {
    for i in indices {
        match mrt {
            MrtTransport::Lightfield(blocks) => write_mat(w, &blocks[i].matrix),
            MrtTransport::Traced(blocks) => write_mat(w, &blocks[i].matrix),
        }
    }
}

/// The key of target block `target`'s matrices beside main entry `key`.
fn target_key(key: &str, target: usize) -> String {
    format!("{key}.t{target}")
}

/// The main entry: the kind, every operator's header, the compaction and the statistics.
fn encode_main(
    traced: bool,
    hs: &[Header],
    compact: Option<&SourceBases>,
    stats: &TransportStats,
) -> Vec<u8> {
    let mut w = Writer::new();
    w.u8(u8::from(traced));
    w.u32(hs.len() as u32);
    for h in hs {
        w.u32(h.target as u32);
        w.u8(h.face.map_or(u8::MAX, |f| f.index() as u8));
        w.u32(h.source as u32);
    }
    match compact {
        None => w.u8(0),
        Some(f) => {
            w.u8(1);
            w.u32(f.bases.len() as u32);
            for b in &f.bases {
                w.u32(b.source_block);
                write_matrix(&mut w, &b.q);
            }
            w.u32(f.entries.len() as u32);
            for c in &f.entries {
                w.u32(c.target_block);
                w.u32s(&c.sources);
                write_matrix(&mut w, &c.y);
                write_matrix(&mut w, &c.z);
            }
        }
    }
    let s = stats;
    let f = &s.factoring;
    for x in [
        s.steps,
        s.cut,
        s.max_hops,
        s.pairs_kept,
        s.pairs_dropped,
        f.sources,
        f.values_before,
        f.values_after,
    ] {
        w.u64(x as u64);
    }
    let u32s = |v: &[usize]| v.iter().map(|r| *r as u32).collect::<Vec<_>>();
    w.u32s(&u32s(&s.compact_ranks));
    w.u32s(&u32s(&f.basis_ranks));
    w.bytes
}

/// What the main entry holds.
struct Main {
    traced: bool,
    headers: Vec<Header>,
    compact: Option<SourceBases>,
    stats: TransportStats,
}

fn decode_main(bytes: &[u8]) -> Result<Main, WireError> {
    let mut r = Reader::new(bytes);
    let traced = match r.u8()? {
        0 => false,
        1 => true,
        _ => return Err(WireError::Invalid("transport kind".into())),
    };
    let n = r.u32()? as usize;
    let mut headers = Vec::with_capacity(n.min(r.remaining() / 9));
    for _ in 0..n {
        let target = r.u32()? as usize;
        let face = match (r.u8()?, traced) {
            (u8::MAX, true) => None,
            (f, false) => Some(
                *Face::ALL
                    .get(f as usize)
                    .ok_or_else(|| WireError::Invalid("face".into()))?,
            ),
            _ => return Err(WireError::Invalid("face".into())),
        };
        let source = r.u32()? as usize;
        headers.push(Header {
            target,
            face,
            source,
        });
    }
    let compact = match r.u8()? {
        0 => None,
        1 => {
            let n = r.u32()? as usize;
            let mut bases = Vec::with_capacity(n.min(r.remaining() / 12));
            for _ in 0..n {
                bases.push(SourceBasis {
                    source_block: r.u32()?,
                    q: read_matrix(&mut r)?,
                });
            }
            let n = r.u32()? as usize;
            let mut entries = Vec::with_capacity(n.min(r.remaining() / 24));
            for _ in 0..n {
                entries.push(CompactEntry {
                    target_block: r.u32()?,
                    sources: r.u32s()?,
                    y: read_matrix(&mut r)?,
                    z: read_matrix(&mut r)?,
                });
            }
            Some(SourceBases { bases, entries })
        }
        _ => return Err(WireError::Invalid("compact flag".into())),
    };
    let mut counters = [0usize; 8];
    for c in &mut counters {
        *c = r.u64()? as usize;
    }
    let mut usizes = || -> Result<Vec<usize>, WireError> {
        Ok(r.u32s()?.into_iter().map(|x| x as usize).collect())
    };
    let compact_ranks = usizes()?;
    let basis_ranks = usizes()?;
    let stats = TransportStats {
        steps: counters[0],
        cut: counters[1],
        max_hops: counters[2],
        pairs_kept: counters[3],
        pairs_dropped: counters[4],
        compact_ranks,
        factoring: FactoringStats {
            basis_ranks,
            sources: counters[5],
            values_before: counters[6],
            values_after: counters[7],
        },
    };
    if r.remaining() != 0 {
        return Err(WireError::Invalid("trailing bytes".into()));
    }
    Ok(Main {
        traced,
        headers,
        compact,
        stats,
    })
}

/// `count` matrices, back to back (one target block's entry).
fn decode_matrices<T: CachedValue>(bytes: &[u8], count: usize) -> Result<Vec<Mat<T>>, WireError> {
    let mut r = Reader::new(bytes);
    let out = (0..count)
        .map(|_| read_mat(&mut r))
        .collect::<Result<Vec<_>, _>>()?;
    if r.remaining() != 0 {
        return Err(WireError::Invalid("trailing bytes".into()));
    }
    Ok(out)
}

/// What a cache hit hands out: the compaction and statistics read, the f64 transport left on
/// disk until someone asks for the blocks it needs.
pub struct CachedHit {
    pub compact: Option<SourceBases>,
    pub stats: TransportStats,
    pub transport: LazyTransport,
}

/// A cached f64 transport read block by block ([`TransportSource`]): each target block's
/// operators are an entry of their own, verified when read. A block that cannot be read drops
/// the main entry, so the next bake computes the transport again.
pub struct LazyTransport {
    store: EntryStore,
    key: String,
    traced: bool,
    headers: Vec<Header>,
}

impl LazyTransport {
    /// The whole transport (every target block).
    pub fn load_all(&self) -> Result<MrtTransport, TransportUnavailable> {
        let all = vec![true; self.headers.iter().map(|h| h.target + 1).max().unwrap_or(0)];
        self.into_targets(&all)
    }

    fn unavailable(&self, block: usize, reason: &str) -> TransportUnavailable {
        let _ = std::fs::remove_file(self.store.path(&self.key));
        TransportUnavailable {
            block,
            reason: reason.to_string(),
        }
    }
}

impl TransportSource for LazyTransport {
    fn into_targets(&self, targets: &[bool]) -> Result<MrtTransport, TransportUnavailable> {
        let marked = |b: usize| targets.get(b).copied().unwrap_or(false);
        let wanted: Vec<&Header> = self.headers.iter().filter(|h| marked(h.target)).collect();
        Ok(if self.traced {
            let mut next = self.reader::<f64>(&wanted)?;
            MrtTransport::Traced(
                wanted
                    .iter()
                    .map(|h| {
                        Ok(TracedBlock {
                            target_block: h.target,
                            source_block: h.source,
                            matrix: next(h)?,
                        })
                    })
                    .collect::<Result<_, _>>()?,
            )
        } else {
            let mut next = self.reader::<f32>(&wanted)?;
            MrtTransport::Lightfield(
                wanted
                    .iter()
                    .map(|h| {
                        Ok(PropBlock {
                            target_block: h.target,
                            target_face: h.face.expect("a lightfield header has a face"),
                            source_block: h.source,
                            matrix: next(h)?,
                        })
                    })
                    .collect::<Result<_, _>>()?,
            )
        })
    }
}

impl LazyTransport {
    /// Reads the entries of the targets of `wanted` (headers in transport order) and hands
    /// out their matrices one header at a time, in that order.
    #[allow(clippy::type_complexity)]
    fn reader<T: CachedValue>(
        &self,
        wanted: &[&Header],
    ) -> Result<
        impl FnMut(&Header) -> Result<Mat<T>, TransportUnavailable> + '_,
        TransportUnavailable,
    > {
        // How many operators each target has, then its matrices, in header order.
        let mut counts: BTreeMap<usize, usize> = BTreeMap::new();
        for h in wanted {
            *counts.entry(h.target).or_default() += 1;
        }
        let mut by_target: BTreeMap<usize, std::vec::IntoIter<Mat<T>>> = BTreeMap::new();
        for (&target, &count) in &counts {
            let mats = self
                .store
                .get(&target_key(&self.key, target), |p| {
                    decode_matrices::<T>(p, count).ok()
                })
                .hit()
                .ok_or_else(|| self.unavailable(target, "missing or corrupt"))?;
            by_target.insert(target, mats.into_iter());
        }
        Ok(move |h: &Header| {
            by_target
                .get_mut(&h.target)
                .and_then(|m| m.next())
                .ok_or_else(|| self.unavailable(h.target, "fewer matrices than operators"))
        })
    }
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

    /// The cached transport, or None (a corrupt main entry is deleted). Only the main entry is
    /// read: the f64 operators stay on disk until [`LazyTransport`] is asked for them.
    pub fn get(&self, key: &str) -> Option<CachedHit> {
        let main = self
            .store
            .get(key, |payload| decode_main(payload).ok())
            .hit()?;
        Some(CachedHit {
            compact: main.compact,
            stats: main.stats,
            transport: LazyTransport {
                store: self.store.clone(),
                key: key.to_string(),
                traced: main.traced,
                headers: main.headers,
            },
        })
    }

    /// A writer of the transport `mrt` (whose operators' headers it notes) under `key`, target
    /// block by target block ([`TransportWriter`]).
    pub fn writer(&self, key: &str, traced: bool) -> TransportWriter {
        TransportWriter {
            store: self.store.clone(),
            key: key.to_string(),
            traced,
            headers: Vec::new(),
        }
    }
}

/// Stores a transport while the bake makes it or lets go of it: each target block's operators
/// as they come ([`TransportWriter::target`], targets ascending) or all at once
/// ([`TransportWriter::all`]), then the main entry ([`TransportWriter::finish`]), which lists
/// every operator stored, in transport order. Until `finish` the transport is not
/// in the cache (a bake that stops half way leaves block entries no main entry points to, which
/// the trim removes like any other).
pub struct TransportWriter {
    store: EntryStore,
    key: String,
    traced: bool,
    headers: Vec<Header>,
}

impl TransportWriter {
    /// Stores the operators into `target` (`part`: the transport into that block alone, in
    /// transport order; targets come ascending, after every earlier one's).
    pub fn target(&mut self, target: usize, part: &MrtTransport) -> std::io::Result<()> {
        self.put_operators(target, part, 0..headers_len(part))?;
        self.headers.extend(headers(part));
        Ok(())
    }

    /// Stores every target's operators of the whole transport `mrt` (grouped by target in one
    /// pass over its headers).
    pub fn all(&mut self, mrt: &MrtTransport) -> std::io::Result<()> {
        self.headers = headers(mrt);
        let mut by_target: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for (i, h) in self.headers.iter().enumerate() {
            by_target.entry(h.target).or_default().push(i);
        }
        for (target, indices) in by_target {
            self.put_operators(target, mrt, indices.into_iter())?;
        }
        Ok(())
    }

    /// Stores the operators `indices` of `mrt` as target `target`'s entry.
    fn put_operators(
        &self,
        target: usize,
        mrt: &MrtTransport,
        indices: impl Iterator<Item = usize>,
    ) -> std::io::Result<()> {
        let mut w = Writer::new();
        write_matrices(&mut w, mrt, indices);
        self.store.put(&target_key(&self.key, target), &w.bytes)
    }

    /// Stores the main entry (the operators' headers, the compaction and the statistics) and
    /// hands back the stored transport as a hit would read it, without reading it back.
    pub fn finish(
        self,
        compact: Option<&SourceBases>,
        stats: &TransportStats,
    ) -> std::io::Result<LazyTransport> {
        self.store.put(
            &self.key,
            &encode_main(self.traced, &self.headers, compact, stats),
        )?;
        Ok(LazyTransport {
            store: self.store,
            key: self.key,
            traced: self.traced,
            headers: self.headers,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A transport as a bake stores it: the operators, the compaction, the statistics.
    struct CachedTransport {
        mrt: MrtTransport,
        compact: Option<SourceBases>,
        stats: TransportStats,
    }

    impl TransportCache {
        /// Stores `transport` whole: each target block's operators, then the main entry.
        fn put(&self, key: &str, transport: &CachedTransport) -> std::io::Result<()> {
            let mut writer = self.writer(key, matches!(transport.mrt, MrtTransport::Traced(_)));
            writer.all(&transport.mrt)?;
            writer
                .finish(transport.compact.as_ref(), &transport.stats)
                .map(|_| ())
        }
    }
    use crate::bake::math::matrix::to_matrix;

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
            factoring: FactoringStats {
                basis_ranks: vec![1],
                sources: 2,
                values_before: 10,
                values_after: 9,
            },
        }
    }

    fn prop(target: usize, face: usize, source: usize, seed: f64) -> PropBlock {
        let m = mat(3, 2, seed);
        PropBlock {
            target_block: target,
            target_face: Face::ALL[face],
            source_block: source,
            matrix: Mat::from_fn(3, 2, |i, j| m[(i, j)] as f32),
        }
    }

    /// Every operator's header and matrix bits, in order.
    fn bits(mrt: &MrtTransport) -> Vec<(Header, Vec<u64>)> {
        fn of<T: Copy>(m: &Mat<T>, to_bits: impl Fn(T) -> u64) -> Vec<u64> {
            let mut b = vec![m.nrows() as u64, m.ncols() as u64];
            for i in 0..m.nrows() {
                for j in 0..m.ncols() {
                    b.push(to_bits(m[(i, j)]));
                }
            }
            b
        }
        let matrices: Vec<Vec<u64>> = match mrt {
            MrtTransport::Lightfield(blocks) => blocks
                .iter()
                .map(|b| of(&b.matrix, |x| u64::from(x.to_bits())))
                .collect(),
            MrtTransport::Traced(blocks) => {
                blocks.iter().map(|b| of(&b.matrix, f64::to_bits)).collect()
            }
        };
        headers(mrt).into_iter().zip(matrices).collect()
    }

    /// A hit reads the main entry only; asked for some target blocks it reads theirs and gives
    /// exactly their operators, in transport order, bit for bit; the whole transport round
    /// trips, lightfield and traced.
    #[test]
    fn transport_round_trips_bit_exact_and_is_read_block_by_block() {
        let root = std::env::temp_dir().join(format!("lf-transport-cache-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let cache = TransportCache::open(&root).unwrap();
        // Targets interleaved, as the propagation lists them.
        let lightfield = CachedTransport {
            mrt: MrtTransport::Lightfield(vec![
                prop(1, 4, 0, 0.1),
                prop(2, 0, 0, 0.2),
                prop(1, 5, 2, 0.3),
                prop(2, 1, 1, 0.4),
            ]),
            compact: None,
            stats: stats(),
        };
        let traced = CachedTransport {
            mrt: MrtTransport::Traced(vec![TracedBlock {
                target_block: 0,
                source_block: 1,
                matrix: mat(4, 3, 0.2),
            }]),
            // Source 1 (r = 3) through a 1 × 3 basis: z is 2 × (2 + 1).
            compact: Some(SourceBases {
                bases: vec![SourceBasis {
                    source_block: 1,
                    q: to_matrix(&mat(1, 3, 0.5)),
                }],
                entries: vec![CompactEntry {
                    target_block: 0,
                    sources: vec![0, 1],
                    y: to_matrix(&mat(4, 2, 0.3)),
                    z: to_matrix(&mat(2, 3, 0.4)),
                }],
            }),
            stats: stats(),
        };
        assert!(cache.get("k").is_none());
        for t in [&lightfield, &traced] {
            cache.put("k", t).unwrap();
            let hit = cache.get("k").expect("a hit");
            assert_eq!(hit.stats, t.stats);
            // The compaction as the bundle ships it, bit for bit.
            assert_eq!(hit.compact, t.compact);
            assert_eq!(bits(&hit.transport.load_all().unwrap()), bits(&t.mrt));
        }

        // Block by block: target 1 alone, then 2 alone, in the order the transport lists them.
        cache.put("k", &lightfield).unwrap();
        let hit = cache.get("k").unwrap();
        let all = bits(&lightfield.mrt);
        for target in [1, 2] {
            let mut marked = vec![false; 3];
            marked[target] = true;
            let want: Vec<_> = all
                .iter()
                .filter(|(h, _)| h.target == target)
                .cloned()
                .collect();
            assert_eq!(want.len(), 2);
            assert_eq!(bits(&hit.transport.into_targets(&marked).unwrap()), want);
        }
        // Held in memory, the same answer.
        assert_eq!(
            bits(&lightfield.mrt.into_targets(&[false, true, false]).unwrap()),
            bits(&hit.transport.into_targets(&[false, true, false]).unwrap())
        );

        // A target block's entry lost (evicted): the read fails, naming the block, and the
        // main entry goes, so the next bake computes the transport again.
        std::fs::remove_file(root.join(ENTRY.relative_path(&target_key("k", 2)))).unwrap();
        assert!(hit.transport.into_targets(&[false, true, false]).is_ok());
        let Err(err) = hit.transport.into_targets(&[false, false, true]) else {
            panic!("a lost block was read");
        };
        assert_eq!(err.block, 2);
        assert!(err.to_string().contains("block 2"), "{err}");
        assert!(cache.get("k").is_none());

        // A corrupt target entry (its own checksum) fails the same way.
        cache.put("k", &lightfield).unwrap();
        let path = root.join(ENTRY.relative_path(&target_key("k", 1)));
        let mut bytes = std::fs::read(&path).unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 1;
        std::fs::write(&path, &bytes).unwrap();
        let hit = cache.get("k").unwrap();
        let Err(err) = hit.transport.load_all() else {
            panic!("a corrupt block was read");
        };
        assert_eq!(err.block, 1);
        assert!(!path.exists() && cache.get("k").is_none());

        // A main entry that does not decode (trailing bytes) is corrupt: deleted and missed.
        cache.put("k", &lightfield).unwrap();
        let mut main = encode_main(
            false,
            &headers(&lightfield.mrt),
            lightfield.compact.as_ref(),
            &lightfield.stats,
        );
        main.push(0);
        cache.store.put("k", &main).unwrap();
        assert!(cache.get("k").is_none());
        assert!(!root.join(ENTRY.relative_path("k")).exists());
        let _ = std::fs::remove_dir_all(&root);
    }
}
