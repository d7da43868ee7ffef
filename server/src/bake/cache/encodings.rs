//! On-disk memo of the bundle writer's matrix encodings ([`EncodingMemo`]): a rebake after a
//! clutter edit writes the same transport and shape matrices as the bake before (about 85% of
//! a 1,000-block level's bundle), and choosing their codecs and predictors is most of the
//! writer's time, so the encodings of the level's last write are kept and handed back.
//!
//! One entry per scene name ([`ENTRY`]: `<dir>/encodings/<key>.lfenc`): the engine build that
//! wrote it, then the encodings of the last bundle written, each under the blake3 of the build,
//! the codec policy, the matrix's size and its value bits. The payload: the build (u32 length,
//! bytes), a count, then per matrix its key (32 bytes), codec tag, 8-bit grid (a tag byte, then
//! for 0 a step, u8, for 1 a floor, f32), error (f64) and bytes (u64 length, then the bytes).
//! Another build's memo is an empty one, which the next save replaces: a level keeps one memo
//! however often the engine is rebuilt.
//! Framing, verification and atomic writes are [`crate::bake::cache::entry`]'s: a stale or
//! corrupt entry is an empty memo.
//!
//! The same memo keeps the level's compressed sections ([`EncodingMemo::section`]): zstd at the
//! bundle's level takes 1.5 s of a 1,000-block rebake on the 100 MB transport section alone,
//! which a clutter edit leaves unchanged. One entry per section kind (`<key>-s<kind>`): the
//! build, the blake3 of the raw payload, the zstd level, then the stored payload (a flag:
//! compressed or stored raw; u64 length; bytes). A section is looked up in this memo's earlier
//! writes first, then in its entry, and compressed only when neither holds it; only sections
//! their entry does not hold yet are rewritten.
//!
//! One memo may serve several writes ([`EncodingCache::begin_write`]): the service encodes each
//! partial bundle it streams and then the whole one, and each write takes what the earlier ones
//! encoded or compressed; [`EncodingCache::save`] stores the latest write's. Between writes the
//! service moves that session to disk ([`EncodingCache::hold_on_disk`]: one scratch entry,
//! `<key>-held`, read back by the next `begin_write`), so the bake's later stages run without
//! it (about 250 MB at 1,000 blocks: the MRT part's encodings and compressed sections).
//!
//! Invariant: an encoding is handed back only for a matrix of the same size and value bits
//! under the same policy, and a compressed section only for the same raw bytes (blake3) at the
//! same level, kept by this same build (`bundle_memo::build_identity`), whose writer
//! is a pure function of those: the bundle is the same bytes with or without it.

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};

use lightfarm_proto::bundle::{EncodingMemo, Matrix, MatrixEncoding};
use lightfarm_proto::codec::{CodecPolicy, MatrixCodec, U8Grid};
use lightfarm_proto::wire::{Reader, WireError, Writer};

use crate::bake::cache::bundle_memo::build_identity;
use crate::bake::cache::entry::{EntryKind, EntryStore};

/// Bumped whenever the key's contents or the payload change.
const CODE_VERSION: &str = "lightfarm-encodings-4";

/// Where encoding memos live and their version.
pub const ENTRY: EntryKind = EntryKind {
    subdir: "encodings",
    extension: "lfenc",
    version: CODE_VERSION,
};

/// A level's matrix encodings: those its last write kept, those this memo's writes made (a
/// service bake encodes partial bundles before the final one), and those the current write
/// keeps.
pub struct EncodingCache {
    store: EntryStore,
    key: String,
    build: Vec<u8>,
    earlier: HashMap<[u8; 32], MatrixEncoding>,
    /// Every encoding this memo's writes made or took, by key.
    session: Mutex<HashMap<[u8; 32], MatrixEncoding>>,
    /// The current write's encodings with their index in it (file order) and key.
    kept: Mutex<Vec<(usize, [u8; 32], MatrixEncoding)>>,
    /// Sections this memo's writes compressed or read, by kind (the latest of each), and
    /// whether the section's entry already holds it.
    session_sections: Mutex<HashMap<u32, (StoredSection, bool)>>,
    /// The current write's sections not read from their entry: to store.
    fresh_sections: Mutex<Vec<(u32, StoredSection)>>,
    /// The session waits on disk ([`EncodingCache::hold_on_disk`]) for the next write.
    held: Mutex<bool>,
}

/// A section's memo entry: the blake3 of its raw payload, the zstd level and the stored payload
/// (None: stored raw), shared between the memo's session, this write's entries and the caller.
#[derive(Clone, Debug, PartialEq)]
struct StoredSection {
    raw_hash: [u8; 32],
    level: i32,
    stored: Option<Arc<Vec<u8>>>,
}

impl EncodingCache {
    /// The memo of `scene_name` by this build in `dir`; None when the build cannot be told.
    pub fn open(dir: &Path, scene_name: &str) -> std::io::Result<Option<EncodingCache>> {
        match build_identity() {
            Some(build) => EncodingCache::open_as(dir, scene_name, build).map(Some),
            None => Ok(None),
        }
    }

    /// [`EncodingCache::open`] as engine build `build`. A memo another build saved is empty
    /// here, and this one's save replaces it: one memo per level, whatever was built before.
    fn open_as(dir: &Path, scene_name: &str, build: Vec<u8>) -> std::io::Result<EncodingCache> {
        let store = EntryStore::open(dir, ENTRY)?;
        let mut h = blake3::Hasher::new();
        h.update(CODE_VERSION.as_bytes());
        h.update(scene_name.as_bytes());
        let key = h.finalize().to_hex().to_string();
        let earlier = store
            .get(&key, |payload| decode(payload).ok())
            .hit()
            .filter(|(by, _)| *by == build)
            .map(|(_, encodings)| encodings)
            .unwrap_or_default();
        Ok(EncodingCache {
            store,
            key,
            build,
            earlier,
            session: Mutex::new(HashMap::new()),
            kept: Mutex::new(Vec::new()),
            session_sections: Mutex::new(HashMap::new()),
            fresh_sections: Mutex::new(Vec::new()),
            held: Mutex::new(false),
        })
    }

    /// Starts another write through this memo: what [`EncodingCache::save`] stores is the
    /// latest write's, while every encoding the earlier ones made is still handed back (the
    /// service encodes each partial bundle it streams, then the whole one).
    pub fn begin_write(&self) {
        self.kept.lock().expect("the memo's lock").clear();
        self.fresh_sections.lock().expect("the memo's lock").clear();
        let mut held = self.held.lock().expect("the memo's lock");
        if std::mem::take(&mut *held) {
            // A lost or corrupt entry is an empty session: the write then encodes and
            // compresses again, to the same bytes.
            let back = self
                .store
                .get(&self.held_key(), |payload| decode_held(payload).ok())
                .hit()
                .filter(|(by, _, _)| *by == self.build);
            if let Some((_, encodings, sections)) = back {
                self.session
                    .lock()
                    .expect("the memo's lock")
                    .extend(encodings);
                self.session_sections
                    .lock()
                    .expect("the memo's lock")
                    .extend(sections);
            }
        }
    }

    /// Moves what this memo's writes made so far (matrix encodings and compressed sections,
    /// which the next write takes back) to a scratch entry on disk and frees them; the next
    /// [`EncodingCache::begin_write`] reads them back. Between a service's partial bundle and
    /// the next one, the bake's later stages then run without them. If the entry cannot be
    /// written they stay in memory (logged): only memory depends on it.
    pub fn hold_on_disk(&self) {
        let mut session = self.session.lock().expect("the memo's lock");
        let mut sections = self.session_sections.lock().expect("the memo's lock");
        if session.is_empty() && sections.is_empty() {
            return;
        }
        let mut w = Writer::new();
        write_build(&mut w, &self.build);
        write_encodings(&mut w, session.iter());
        w.u32(sections.len() as u32);
        for (kind, (section, in_entry)) in sections.iter() {
            w.u32(*kind);
            w.u8(*in_entry as u8);
            let payload = encode_section(&self.build, section);
            w.u64(payload.len() as u64);
            w.bytes.extend_from_slice(&payload);
        }
        if let Err(e) = self.store.put(&self.held_key(), &w.bytes) {
            tracing::warn!(error = %e, "encoding memo: could not hold the session on disk");
            return;
        }
        session.clear();
        sections.clear();
        self.kept.lock().expect("the memo's lock").clear();
        self.fresh_sections.lock().expect("the memo's lock").clear();
        *self.held.lock().expect("the memo's lock") = true;
    }

    fn held_key(&self) -> String {
        format!("{}-held", self.key)
    }

    /// How many encodings the last write kept.
    pub fn earlier(&self) -> usize {
        self.earlier.len()
    }

    /// Stores what this write kept (replacing the last write's): its matrix encodings, and the
    /// sections it compressed afresh (the others' entries already hold them).
    pub fn save(&self) -> std::io::Result<()> {
        let mut kept = self.kept.lock().expect("the memo's lock");
        // File order, whichever thread kept each: the same entry bytes for the same write.
        kept.sort_unstable_by_key(|(index, _, _)| *index);
        self.store.put(&self.key, &encode(&self.build, &kept))?;
        let fresh = self.fresh_sections.lock().expect("the memo's lock");
        let mut session = self.session_sections.lock().expect("the memo's lock");
        for (kind, section) in fresh.iter() {
            self.store.put(
                &self.section_key(*kind),
                &encode_section(&self.build, section),
            )?;
            if let Some((held, in_entry)) = session.get_mut(kind) {
                *in_entry |= held == section;
            }
        }
        Ok(())
    }

    fn section_key(&self, kind: u32) -> String {
        format!("{}-s{kind}", self.key)
    }

    fn matrix_key(&self, m: &Matrix, policy: CodecPolicy) -> [u8; 32] {
        let mut h = blake3::Hasher::new();
        h.update(&self.build);
        h.update(format!("{policy:?}").as_bytes());
        h.update(&m.rows.to_le_bytes());
        h.update(&m.cols.to_le_bytes());
        // The value bits, little-endian, through a small buffer (a byte at a time through an
        // iterator was a copy of every matrix at a few hundred MB/s).
        let mut bits = Vec::with_capacity(4 * 4096);
        for chunk in m.data.chunks(4096) {
            bits.clear();
            for x in chunk {
                bits.extend_from_slice(&x.to_le_bytes());
            }
            h.update(&bits);
        }
        *h.finalize().as_bytes()
    }
}

impl EncodingMemo for EncodingCache {
    fn encoding(
        &self,
        index: usize,
        m: &Matrix,
        policy: CodecPolicy,
        encode: &dyn Fn() -> MatrixEncoding,
    ) -> MatrixEncoding {
        let key = self.matrix_key(m, policy);
        let made = || {
            let session = self
                .session
                .lock()
                .expect("the memo's lock")
                .get(&key)
                .cloned();
            session.unwrap_or_else(|| {
                let e = encode();
                self.session
                    .lock()
                    .expect("the memo's lock")
                    .insert(key, e.clone());
                e
            })
        };
        let e = self.earlier.get(&key).cloned().unwrap_or_else(made);
        self.kept
            .lock()
            .expect("the memo's lock")
            .push((index, key, e.clone()));
        e
    }

    fn section(
        &self,
        kind: u32,
        raw: &[u8],
        level: i32,
        compress: &dyn Fn() -> Option<Vec<u8>>,
    ) -> Option<Vec<u8>> {
        let raw_hash = *blake3::hash(raw).as_bytes();
        let same = |e: &StoredSection| e.raw_hash == raw_hash && e.level == level;
        // This memo's earlier writes first (in memory: a service's partial bundle, then the
        // whole), then the section's entry, then compressed now.
        let session = self
            .session_sections
            .lock()
            .expect("the memo's lock")
            .get(&kind)
            .filter(|(e, _)| same(e))
            .cloned();
        let (section, in_entry) = session.unwrap_or_else(|| {
            let earlier = self
                .store
                .get(&self.section_key(kind), |payload| {
                    decode_section(payload).ok()
                })
                .hit()
                .filter(|(by, e)| *by == self.build && same(e))
                .map(|(_, e)| e);
            match earlier {
                Some(e) => (e, true),
                None => (
                    StoredSection {
                        raw_hash,
                        level,
                        stored: compress().map(Arc::new),
                    },
                    false,
                ),
            }
        });
        self.session_sections
            .lock()
            .expect("the memo's lock")
            .insert(kind, (section.clone(), in_entry));
        let stored = section.stored.as_deref().cloned();
        if !in_entry {
            // Stored with this write.
            self.fresh_sections
                .lock()
                .expect("the memo's lock")
                .push((kind, section));
        }
        stored
    }
}

fn encode_section(build: &[u8], s: &StoredSection) -> Vec<u8> {
    let mut w = Writer::new();
    write_build(&mut w, build);
    w.bytes.extend_from_slice(&s.raw_hash);
    w.u32(s.level as u32);
    match &s.stored {
        Some(bytes) => {
            w.u8(1);
            w.u64(bytes.len() as u64);
            w.bytes.extend_from_slice(bytes);
        }
        None => w.u8(0),
    }
    w.bytes
}

/// The build that saved a section entry, and the section.
fn decode_section(payload: &[u8]) -> Result<(Vec<u8>, StoredSection), WireError> {
    let mut r = Reader::new(payload);
    let build = read_build(&mut r)?;
    let raw_hash: [u8; 32] = r.take(32)?.try_into().expect("32 bytes");
    let level = r.u32()? as i32;
    let stored = match r.u8()? {
        0 => None,
        1 => {
            let len = usize::try_from(r.u64()?)
                .ok()
                .filter(|&len| len == r.remaining())
                .ok_or_else(|| WireError::Invalid("section length".into()))?;
            Some(Arc::new(r.take(len)?.to_vec()))
        }
        _ => return Err(WireError::Invalid("section flag".into())),
    };
    if r.remaining() != 0 {
        return Err(WireError::Invalid("trailing bytes".into()));
    }
    Ok((
        build,
        StoredSection {
            raw_hash,
            level,
            stored,
        },
    ))
}

/// The build that saved an entry, first in every payload.
fn write_build(w: &mut Writer, build: &[u8]) {
    w.u32(build.len() as u32);
    w.bytes.extend_from_slice(build);
}

fn read_build(r: &mut Reader) -> Result<Vec<u8>, WireError> {
    let len = r.u32()? as usize;
    Ok(r.take(len)?.to_vec())
}

fn encode(build: &[u8], kept: &[(usize, [u8; 32], MatrixEncoding)]) -> Vec<u8> {
    let mut w = Writer::new();
    write_build(&mut w, build);
    write_encodings(&mut w, kept.iter().map(|(_, key, e)| (key, e)));
    w.bytes
}

/// A count, then per matrix its key, codec tag, 8-bit grid, error and bytes.
fn write_encodings<'a>(
    w: &mut Writer,
    encodings: impl ExactSizeIterator<Item = (&'a [u8; 32], &'a MatrixEncoding)>,
) {
    w.u32(encodings.len() as u32);
    for (key, e) in encodings {
        w.bytes.extend_from_slice(key);
        w.u8(e.codec.tag());
        match e.grid {
            U8Grid::Step(step) => {
                w.u8(0);
                w.u8(step);
            }
            U8Grid::Floor(floor) => {
                w.u8(1);
                w.f32(floor);
            }
        }
        w.f64(e.error);
        w.u64(e.bytes.len() as u64);
        w.bytes.extend_from_slice(&e.bytes);
    }
}

/// A held session ([`EncodingCache::hold_on_disk`]): the build, its encodings and its sections
/// with whether their entry holds them.
type Held = (Vec<u8>, Encodings, Vec<(u32, (StoredSection, bool))>);

fn decode_held(payload: &[u8]) -> Result<Held, WireError> {
    let mut r = Reader::new(payload);
    let build = read_build(&mut r)?;
    let encodings = read_encodings(&mut r)?;
    let n = r.u32()? as usize;
    let mut sections = Vec::with_capacity(n.min(64));
    for _ in 0..n {
        let kind = r.u32()?;
        let in_entry = r.u8()? != 0;
        let len = usize::try_from(r.u64()?)
            .ok()
            .filter(|&len| len <= r.remaining())
            .ok_or_else(|| WireError::Invalid("section longer than the entry".into()))?;
        let (_, section) = decode_section(r.take(len)?)?;
        sections.push((kind, (section, in_entry)));
    }
    if r.remaining() != 0 {
        return Err(WireError::Invalid("trailing bytes".into()));
    }
    Ok((build, encodings, sections))
}

type Encodings = HashMap<[u8; 32], MatrixEncoding>;

/// The build that saved a memo, and its encodings.
fn decode(payload: &[u8]) -> Result<(Vec<u8>, Encodings), WireError> {
    let mut r = Reader::new(payload);
    let build = read_build(&mut r)?;
    let out = read_encodings(&mut r)?;
    if r.remaining() != 0 {
        return Err(WireError::Invalid("trailing bytes".into()));
    }
    Ok((build, out))
}

/// What [`write_encodings`] wrote.
fn read_encodings(r: &mut Reader) -> Result<Encodings, WireError> {
    let n = r.u32()? as usize;
    let mut out = HashMap::with_capacity(n.min(r.remaining() / 50));
    for _ in 0..n {
        let key: [u8; 32] = r.take(32)?.try_into().expect("32 bytes");
        let codec =
            MatrixCodec::from_tag(r.u8()?).ok_or_else(|| WireError::Invalid("codec tag".into()))?;
        let grid = match r.u8()? {
            0 => U8Grid::Step(r.u8()?),
            1 => U8Grid::Floor(r.f32()?),
            _ => return Err(WireError::Invalid("8-bit grid tag".into())),
        };
        let error = r.f64()?;
        let len = usize::try_from(r.u64()?)
            .ok()
            .filter(|&len| len <= r.remaining())
            .ok_or_else(|| WireError::Invalid("encoding longer than the entry".into()))?;
        let bytes = std::sync::Arc::new(r.take(len)?.to_vec());
        out.insert(
            key,
            MatrixEncoding {
                bytes,
                codec,
                grid,
                error,
            },
        );
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::bundle::EncodeOptions;
    use lightfarm_proto::testing::{drt_bundle, Lcg};

    /// The encode options every test here writes with (8-bit codecs in play, fast zstd).
    fn options() -> EncodeOptions {
        EncodeOptions {
            codec: CodecPolicy::Budget(0.02),
            transport_codec: Some(CodecPolicy::Budget(0.002)),
            zstd_level: 3,
        }
    }

    /// An empty directory of the test's own (`name` and this process).
    /// Corrupts the file at `path`: byte `at` xor `mask`.
    fn flip_byte(path: &std::path::Path, at: usize, mask: u8) {
        let mut raw = std::fs::read(path).unwrap();
        raw[at] ^= mask;
        std::fs::write(path, &raw).unwrap();
    }

    fn fresh_dir(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    /// A level's second write takes its matrices from the memo the first one saved and gives
    /// the same bytes; a corrupt memo is an empty one (the same bytes again, encoded).
    #[test]
    fn a_saved_memo_writes_the_same_bytes_and_a_corrupt_one_is_empty() {
        let dir = fresh_dir("lf-encodings");
        let bundle = drt_bundle(&mut Lcg(5), true, true, false);
        let options = options();
        let (want, _) = bundle.encode_on(&options, 1);
        let first = EncodingCache::open(&dir, "level").unwrap().unwrap();
        assert_eq!(first.earlier(), 0);
        let (bytes, _) = bundle.encode_memo(&options, 2, Some(&first));
        assert!(bytes == want);
        first.save().unwrap();
        let kept = first.kept.lock().unwrap().len();
        assert!(kept > 10);

        let second = EncodingCache::open(&dir, "level").unwrap().unwrap();
        assert_eq!(second.earlier(), kept);
        let (bytes, _) = bundle.encode_memo(&options, 2, Some(&second));
        assert!(bytes == want);
        // Another level's memo is its own.
        assert_eq!(
            EncodingCache::open(&dir, "other")
                .unwrap()
                .unwrap()
                .earlier(),
            0
        );

        let path = second.store.path(&second.key);
        flip_byte(
            &path,
            std::fs::metadata(&path).unwrap().len() as usize / 2,
            0x20,
        );
        let third = EncodingCache::open(&dir, "level").unwrap().unwrap();
        assert_eq!(third.earlier(), 0);
        let (bytes, _) = bundle.encode_memo(&options, 2, Some(&third));
        assert!(bytes == want);
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// Sections the last write compressed are handed back when their raw bytes are the same
    /// (nothing compressed afresh), compressed again when they changed or their entry is
    /// corrupt, and the bundle is the same bytes every time.
    #[test]
    fn unchanged_sections_are_not_compressed_again() {
        let dir = fresh_dir("lf-sections");
        let options = options();
        let bundle = drt_bundle(&mut Lcg(7), true, true, false);
        let (want, _) = bundle.encode_on(&options, 1);
        let fresh = |memo: &EncodingCache| memo.fresh_sections.lock().unwrap().len();

        let first = EncodingCache::open(&dir, "level").unwrap().unwrap();
        assert!(bundle.encode_memo(&options, 2, Some(&first)).0 == want);
        let sections = fresh(&first);
        assert!(sections >= 4, "{sections} sections");
        first.save().unwrap();

        let second = EncodingCache::open(&dir, "level").unwrap().unwrap();
        assert!(bundle.encode_memo(&options, 2, Some(&second)).0 == want);
        assert_eq!(fresh(&second), 0);

        // A corrupt entry is compressed again, alone.
        let path = second
            .store
            .path(&second.section_key(lightfarm_proto::bundle::section::LAYOUT));
        flip_byte(
            &path,
            std::fs::metadata(&path).unwrap().len() as usize - 1,
            0x01,
        );
        let third = EncodingCache::open(&dir, "level").unwrap().unwrap();
        assert!(bundle.encode_memo(&options, 2, Some(&third)).0 == want);
        assert_eq!(fresh(&third), 1);
        third.save().unwrap();

        // Another bundle under the same name: its sections differ, and its bytes are its own.
        let other = drt_bundle(&mut Lcg(8), true, true, false);
        let (other_want, _) = other.encode_on(&options, 1);
        let fourth = EncodingCache::open(&dir, "level").unwrap().unwrap();
        assert!(other.encode_memo(&options, 2, Some(&fourth)).0 == other_want);
        assert!(fresh(&fourth) >= 1);
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// One memo serving the partial bundle a service streams and then the whole one: the
    /// whole write takes the partial's encodings (the same shared bytes, not encoded again),
    /// both give the plain writer's bytes, and the saved memo is the whole write's.
    #[test]
    fn one_memo_serves_a_partial_write_then_the_whole() {
        let dir = fresh_dir("lf-session");
        let options = options();
        let whole = drt_bundle(&mut Lcg(9), true, true, false);
        let mut partial = whole.clone();
        partial.drt = None;
        let memo = EncodingCache::open(&dir, "level").unwrap().unwrap();
        memo.begin_write();
        assert!(
            partial.encode_memo(&options, 2, Some(&memo)).0 == partial.encode_on(&options, 1).0
        );
        let from_partial: HashMap<[u8; 32], MatrixEncoding> = memo.session.lock().unwrap().clone();
        assert!(!from_partial.is_empty());
        let sections_from_partial = memo.session_sections.lock().unwrap().clone();
        assert!(!sections_from_partial.is_empty());
        memo.begin_write();
        assert!(whole.encode_memo(&options, 2, Some(&memo)).0 == whole.encode_on(&options, 1).0);
        let kept = memo.kept.lock().unwrap().clone();
        assert!(kept.len() > from_partial.len());
        let mut shared = 0;
        for (_, key, e) in &kept {
            if let Some(p) = from_partial.get(key) {
                assert!(std::sync::Arc::ptr_eq(&p.bytes, &e.bytes), "encoded again");
                shared += 1;
            }
        }
        assert!(shared >= from_partial.len());
        // The partial's unchanged sections are the same shared bytes, not compressed again,
        // and stored with the whole write (the partial's write was never saved).
        let sections = memo.session_sections.lock().unwrap().clone();
        let mut shared_sections = 0;
        for (kind, (p, _)) in &sections_from_partial {
            let (w, in_entry) = &sections[kind];
            assert!(!in_entry);
            if w.raw_hash == p.raw_hash {
                if let (Some(a), Some(b)) = (&p.stored, &w.stored) {
                    assert!(
                        std::sync::Arc::ptr_eq(a, b),
                        "section {kind} compressed again"
                    );
                }
                shared_sections += 1;
            }
        }
        assert!(shared_sections >= 1);
        assert_eq!(memo.fresh_sections.lock().unwrap().len(), sections.len());
        memo.save().unwrap();
        assert!(memo
            .session_sections
            .lock()
            .unwrap()
            .values()
            .all(|(_, in_entry)| *in_entry));
        let keys: std::collections::HashSet<_> = kept.iter().map(|(_, k, _)| *k).collect();
        let reopened = EncodingCache::open(&dir, "level").unwrap().unwrap();
        assert_eq!(reopened.earlier(), keys.len());
        // Every section of the whole write is in its entry: another write compresses none.
        assert!(
            whole.encode_memo(&options, 2, Some(&reopened)).0 == whole.encode_on(&options, 1).0
        );
        assert_eq!(reopened.fresh_sections.lock().unwrap().len(), 0);
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A session held on disk between a partial write and the whole one leaves nothing in
    /// memory, comes back whole with the next write (every encoding and compressed section of
    /// the partial write, so none is made again), and the whole write gives the plain writer's
    /// bytes; a lost held entry only means encoding again, to the same bytes.
    #[test]
    fn a_session_held_on_disk_comes_back_with_the_next_write() {
        let dir = fresh_dir("lf-held");
        let options = options();
        let whole = drt_bundle(&mut Lcg(11), true, true, false);
        let mut partial = whole.clone();
        partial.drt = None;
        let want = whole.encode_on(&options, 1).0;
        for lose_it in [false, true] {
            let memo = EncodingCache::open(&dir, &format!("level-{lose_it}"))
                .unwrap()
                .unwrap();
            memo.begin_write();
            assert!(
                partial.encode_memo(&options, 2, Some(&memo)).0 == partial.encode_on(&options, 1).0
            );
            let encodings = memo.session.lock().unwrap().clone();
            let sections = memo.session_sections.lock().unwrap().clone();
            assert!(!encodings.is_empty() && !sections.is_empty());
            memo.hold_on_disk();
            assert!(memo.session.lock().unwrap().is_empty());
            assert!(memo.session_sections.lock().unwrap().is_empty());
            assert!(memo.kept.lock().unwrap().is_empty());
            if lose_it {
                std::fs::remove_file(memo.store.path(&memo.held_key())).unwrap();
            }
            memo.begin_write();
            if lose_it {
                assert!(memo.session.lock().unwrap().is_empty());
            } else {
                assert_eq!(*memo.session.lock().unwrap(), encodings);
                assert_eq!(*memo.session_sections.lock().unwrap(), sections);
            }
            assert!(whole.encode_memo(&options, 2, Some(&memo)).0 == want);
            // Held once, read back once.
            assert!(!*memo.held.lock().unwrap());
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A memo another engine build saved is empty to this one (its encodings and sections may
    /// not be this build's bytes), and this build's save replaces it: one memo per level.
    #[test]
    fn another_builds_memo_is_empty_and_replaced() {
        let dir = fresh_dir("lf-builds");
        let options = options();
        let bundle = drt_bundle(&mut Lcg(11), true, true, false);
        let (want, _) = bundle.encode_on(&options, 1);
        let files = || std::fs::read_dir(dir.join("encodings")).unwrap().count();
        let a = EncodingCache::open_as(&dir, "level", b"build a".to_vec()).unwrap();
        assert!(bundle.encode_memo(&options, 2, Some(&a)).0 == want);
        a.save().unwrap();
        let saved = files();
        let a_again = EncodingCache::open_as(&dir, "level", b"build a".to_vec()).unwrap();
        assert!(a_again.earlier() > 0);
        let b = EncodingCache::open_as(&dir, "level", b"build b".to_vec()).unwrap();
        assert_eq!(b.earlier(), 0);
        assert!(bundle.encode_memo(&options, 2, Some(&b)).0 == want);
        let sections = b.fresh_sections.lock().unwrap().len();
        assert!(sections >= 4, "another build's sections were taken");
        b.save().unwrap();
        assert_eq!(files(), saved);
        let a_later = EncodingCache::open_as(&dir, "level", b"build a".to_vec()).unwrap();
        assert_eq!(a_later.earlier(), 0);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
