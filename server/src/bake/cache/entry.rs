//! The one on-disk entry format of every bake cache, and the store that reads and writes it.
//! Each cache keeps its own key and payload serialization; this module owns everything else:
//! where an entry lives, its framing, atomic writes, verification and marking use.
//!
//! Naming: a cache is an [`EntryKind`] — a subdirectory of the operator cache directory (empty
//! for the directory itself), a file extension and a version tag. Entry `key` lives at
//! `<root>/<subdir>/<key>.<extension>`; [`EntryKind::relative_path`] is that path relative to
//! `<root>`, which the farm's unit inputs and cache sync name files by.
//!
//! Framing (little-endian):
//!
//! | bytes | field                                                        |
//! |-------|--------------------------------------------------------------|
//! | 8     | [`MAGIC`] (`lfentry` + framing version 2)                     |
//! | 2     | tag length `n` (u16)                                          |
//! | n     | the kind's version tag (UTF-8)                                |
//! | 8     | payload length (u64)                                          |
//! | 8     | checksum of the payload ([`checksum`]: blake3's first 8 bytes) |
//! | …     | payload                                                       |
//!
//! Invariants:
//! - A write goes to a temp file in the entry's directory (named `.<key>.<pid>-<n>.tmp`, unique
//!   per write, so concurrent writers of one key in one process or many never share one) and is
//!   renamed into place: a reader sees a whole old entry, a whole new one, or none. Names starting
//!   with `.` are writes in flight, which the service's trimmer leaves alone.
//! - A write is not flushed to the disk (no `fsync`): these are caches, every read verifies
//!   every byte, and an entry a power cut left half-written is corrupt, deleted and recomputed.
//!   Flushing cost a rebake of a 1,000-block level a write-out of each of its entries (the
//!   encoding memo alone is 150 MB).
//! - A read is a hit only when every byte verifies: magic, tag, length and checksum, then the
//!   cache's own decoding. A stale entry (other magic — including the caches' unframed format
//!   before this one — or another version tag) is a [`Lookup::Miss`] and is left for the next
//!   write to replace; a corrupt one (short, wrong length or checksum, or the payload does not
//!   decode) is deleted and reported as [`Lookup::Corrupt`]. Neither panics nor returns data.
//! - A hit marks the entry used ([`mark_used`]: its modification time becomes now), as every
//!   write does, so least-recently-used trimming by modification time is meaningful.
//! - Framing is deterministic: the same payload gives the same file bytes.
//!
//! Framing version 1 checksummed with FNV-1a, a byte at a time (0.3 GB/s: 3 s of a 1,000-block
//! rebake's reading of 1.1 GB of shape operators); its entries are stale, so misses.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// First bytes of every entry: `lfentry` and the framing version.
pub const MAGIC: [u8; 8] = *b"lfentry\x02";

/// The payload checksum of the framing: the first 8 bytes of its blake3 hash (SIMD, several
/// GB/s), little-endian.
pub fn checksum(payload: &[u8]) -> u64 {
    let hash = blake3::hash(payload);
    u64::from_le_bytes(hash.as_bytes()[..8].try_into().expect("8 bytes"))
}

/// Distinguishes temp files of concurrent writes within one process.
static WRITES: AtomicU64 = AtomicU64::new(0);

/// One cache's place and version in the operator cache directory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EntryKind {
    /// Subdirectory of the operator cache directory; empty for the directory itself.
    pub subdir: &'static str,
    /// File extension, without the dot.
    pub extension: &'static str,
    /// Stored in every entry and compared on read: bump it whenever the payload's format or
    /// what is computed for the same key changes, and old entries become misses.
    pub version: &'static str,
}

impl EntryKind {
    /// Where entry `key` lives, relative to the operator cache directory.
    pub fn relative_path(&self, key: &str) -> PathBuf {
        let name = format!("{key}.{}", self.extension);
        if self.subdir.is_empty() {
            PathBuf::from(name)
        } else {
            Path::new(self.subdir).join(name)
        }
    }
}

/// What a lookup found.
#[derive(Debug)]
pub enum Lookup<T> {
    Hit(T),
    /// No entry, or a stale one (another framing or version).
    Miss,
    /// An entry was there but corrupt; it has been removed.
    Corrupt,
}

impl<T> Lookup<T> {
    /// The hit, if any.
    pub fn hit(self) -> Option<T> {
        match self {
            Lookup::Hit(t) => Some(t),
            Lookup::Miss | Lookup::Corrupt => None,
        }
    }
}

/// Why a file's bytes are not a valid entry.
#[derive(Debug, PartialEq, Eq)]
enum Invalid {
    /// Another framing or version tag: not ours to judge.
    Stale,
    /// Ours but damaged.
    Corrupt,
}

/// The header of an entry of version `version` holding `payload`.
fn header(version: &str, payload: &[u8]) -> Vec<u8> {
    let tag = version.as_bytes();
    let tag_len = u16::try_from(tag.len()).expect("version tags are short");
    let mut h = Vec::with_capacity(MAGIC.len() + 2 + tag.len() + 16);
    h.extend_from_slice(&MAGIC);
    h.extend_from_slice(&tag_len.to_le_bytes());
    h.extend_from_slice(tag);
    h.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    h.extend_from_slice(&checksum(payload).to_le_bytes());
    h
}

/// The whole entry file of version `version` holding `payload`.
pub fn frame(version: &str, payload: &[u8]) -> Vec<u8> {
    let mut bytes = header(version, payload);
    bytes.extend_from_slice(payload);
    bytes
}

/// The payload of the entry file `bytes` if it is a valid entry of version `version`.
fn unframe<'a>(version: &str, bytes: &'a [u8]) -> Result<&'a [u8], Invalid> {
    let rest = bytes
        .strip_prefix(&MAGIC)
        .ok_or(if bytes.len() < MAGIC.len() {
            Invalid::Corrupt
        } else {
            Invalid::Stale
        })?;
    let (tag_len, rest) = split(rest, 2)?;
    let tag_len = u16::from_le_bytes(tag_len.try_into().unwrap()) as usize;
    let (tag, rest) = split(rest, tag_len)?;
    if tag != version.as_bytes() {
        return Err(Invalid::Stale);
    }
    let (len, rest) = split(rest, 8)?;
    let (sum, payload) = split(rest, 8)?;
    let ok = u64::from_le_bytes(len.try_into().unwrap()) == payload.len() as u64
        && u64::from_le_bytes(sum.try_into().unwrap()) == checksum(payload);
    ok.then_some(payload).ok_or(Invalid::Corrupt)
}

/// `bytes` split after `n`; a shorter slice is a truncated entry.
fn split(bytes: &[u8], n: usize) -> Result<(&[u8], &[u8]), Invalid> {
    (bytes.len() >= n)
        .then(|| bytes.split_at(n))
        .ok_or(Invalid::Corrupt)
}

/// Marks a cache file as just used (its modification time), for least-recently-used trimming
/// by whoever bounds the cache's size. Best effort: a failure only makes the entry look older.
pub fn mark_used(path: &Path) {
    if let Ok(f) = fs::File::options().append(true).open(path) {
        let _ = f.set_modified(std::time::SystemTime::now());
    }
}

/// A directory of entries of one [`EntryKind`].
#[derive(Clone, Debug)]
pub struct EntryStore {
    dir: PathBuf,
    kind: EntryKind,
}

impl EntryStore {
    /// Opens (and creates) `<root>/<kind.subdir>`.
    pub fn open(root: impl Into<PathBuf>, kind: EntryKind) -> std::io::Result<EntryStore> {
        let root = root.into();
        let dir = if kind.subdir.is_empty() {
            root
        } else {
            root.join(kind.subdir)
        };
        fs::create_dir_all(&dir)?;
        Ok(EntryStore { dir, kind })
    }

    /// The directory the entries are in.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn kind(&self) -> EntryKind {
        self.kind
    }

    /// The file of entry `key`.
    pub fn path(&self, key: &str) -> PathBuf {
        self.dir.join(format!("{key}.{}", self.kind.extension))
    }

    /// Entry `key`, its payload read by `decode` (None: it does not decode, and the entry is
    /// corrupt). A hit is marked used.
    pub fn get<T>(&self, key: &str, decode: impl FnOnce(&[u8]) -> Option<T>) -> Lookup<T> {
        let path = self.path(key);
        let Ok(bytes) = fs::read(&path) else {
            return Lookup::Miss;
        };
        match unframe(self.kind.version, &bytes).map(decode) {
            Ok(Some(t)) => {
                mark_used(&path);
                Lookup::Hit(t)
            }
            Err(Invalid::Stale) => Lookup::Miss,
            Ok(None) | Err(Invalid::Corrupt) => {
                let _ = fs::remove_file(&path);
                Lookup::Corrupt
            }
        }
    }

    /// Stores `payload` as entry `key`, atomically (temp file, then rename).
    pub fn put(&self, key: &str, payload: &[u8]) -> std::io::Result<()> {
        let tmp = self.dir.join(format!(
            ".{key}.{}-{}.tmp",
            std::process::id(),
            WRITES.fetch_add(1, Ordering::Relaxed)
        ));
        let write = || -> std::io::Result<()> {
            let mut f = fs::File::create(&tmp)?;
            f.write_all(&header(self.kind.version, payload))?;
            f.write_all(payload)?;
            drop(f);
            fs::rename(&tmp, self.path(key))
        };
        let result = write();
        if result.is_err() {
            let _ = fs::remove_file(&tmp);
        }
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, SystemTime};

    const KIND: EntryKind = EntryKind {
        subdir: "things",
        extension: "lfthing",
        version: "thing/1",
    };

    /// A fresh store under a directory unique to the test.
    fn store(test: &str) -> EntryStore {
        let root = std::env::temp_dir().join(format!("lf-entry-{test}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&root);
        EntryStore::open(&root, KIND).unwrap()
    }

    fn cleanup(s: &EntryStore) {
        let _ = fs::remove_dir_all(s.dir().parent().unwrap());
    }

    /// A store of the same kind and directory as `s` but another version.
    fn other_version(s: &EntryStore, version: &'static str) -> EntryStore {
        let kind = EntryKind { version, ..KIND };
        EntryStore::open(s.dir().parent().unwrap(), kind).unwrap()
    }

    fn payload(n: usize, seed: u8) -> Vec<u8> {
        (0..n).map(|i| (i as u8).wrapping_mul(31) ^ seed).collect()
    }

    fn get(s: &EntryStore, key: &str) -> Lookup<Vec<u8>> {
        s.get(key, |p| Some(p.to_vec()))
    }

    #[test]
    fn entry_round_trips_and_is_named_by_kind() {
        let s = store("round-trip");
        let data = payload(1000, 7);
        assert!(matches!(get(&s, "k"), Lookup::Miss));
        s.put("k", &data).unwrap();
        assert_eq!(s.path("k"), s.dir().join("k.lfthing"));
        assert_eq!(
            s.dir().parent().unwrap().join(KIND.relative_path("k")),
            s.path("k")
        );
        assert_eq!(fs::read(s.path("k")).unwrap(), frame(KIND.version, &data));
        match get(&s, "k") {
            Lookup::Hit(p) => assert_eq!(p, data),
            other => panic!("expected a hit, got {other:?}"),
        }
        // An empty payload is an entry too; writing again replaces the entry whole.
        s.put("k", &[]).unwrap();
        assert_eq!(get(&s, "k").hit(), Some(Vec::new()));
        // No temp files are left behind.
        let names: Vec<_> = fs::read_dir(s.dir())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["k.lfthing"]);
        cleanup(&s);
    }

    #[test]
    fn entry_in_the_root_directory_has_no_subdirectory() {
        let kind = EntryKind { subdir: "", ..KIND };
        assert_eq!(kind.relative_path("k"), PathBuf::from("k.lfthing"));
        let root = std::env::temp_dir().join(format!("lf-entry-root-{}", std::process::id()));
        let s = EntryStore::open(&root, kind).unwrap();
        assert_eq!(s.dir(), root);
        let _ = fs::remove_dir_all(&root);
    }

    #[test]
    fn entry_with_any_flipped_payload_byte_is_corrupt_and_removed() {
        let s = store("flip");
        let data = payload(64, 1);
        let header_len = frame(KIND.version, &[]).len();
        for i in [0, 31, 63] {
            s.put("k", &data).unwrap();
            let mut bytes = fs::read(s.path("k")).unwrap();
            bytes[header_len + i] ^= 0x10;
            fs::write(s.path("k"), &bytes).unwrap();
            assert!(matches!(get(&s, "k"), Lookup::Corrupt), "byte {i}");
            assert!(!s.path("k").exists());
            assert!(matches!(get(&s, "k"), Lookup::Miss));
        }
        // So is a flipped length or checksum.
        for i in [header_len - 16, header_len - 1] {
            s.put("k", &data).unwrap();
            let mut bytes = fs::read(s.path("k")).unwrap();
            bytes[i] ^= 0x01;
            fs::write(s.path("k"), &bytes).unwrap();
            assert!(matches!(get(&s, "k"), Lookup::Corrupt), "header byte {i}");
        }
        cleanup(&s);
    }

    #[test]
    fn entry_of_another_version_or_framing_is_a_miss() {
        let s = store("version");
        let data = payload(100, 2);
        let newer = other_version(&s, "thing/2");
        s.put("k", &data).unwrap();
        assert!(matches!(get(&newer, "k"), Lookup::Miss));
        // Left for the next write, which replaces it.
        assert!(s.path("k").exists());
        newer.put("k", &data).unwrap();
        assert_eq!(get(&newer, "k").hit(), Some(data.clone()));
        assert!(matches!(get(&s, "k"), Lookup::Miss));
        // Framing version 1 (FNV-1a checksums) is a miss.
        let mut v1 = frame(KIND.version, &data);
        v1[7] = 1;
        let fnv = lightfarm_proto::wire::checksum(&data).to_le_bytes();
        let at = v1.len() - data.len() - 8;
        v1[at..at + 8].copy_from_slice(&fnv);
        fs::write(s.path("k"), &v1).unwrap();
        assert!(matches!(get(&s, "k"), Lookup::Miss));
        assert!(s.path("k").exists());
        // The unframed format before those (checksum ‖ payload) is a miss too.
        let mut old = lightfarm_proto::wire::checksum(&data)
            .to_le_bytes()
            .to_vec();
        old.extend_from_slice(&data);
        fs::write(s.path("k"), &old).unwrap();
        assert!(matches!(get(&s, "k"), Lookup::Miss));
        cleanup(&s);
    }

    #[test]
    fn entry_truncated_anywhere_is_corrupt() {
        let s = store("truncated");
        let data = payload(300, 3);
        let whole = frame(KIND.version, &data).len();
        for len in [0, 3, 8, 9, 12, 20, whole - 300, whole - 150, whole - 1] {
            s.put("k", &data).unwrap();
            let f = fs::File::options().write(true).open(s.path("k")).unwrap();
            f.set_len(len as u64).unwrap();
            drop(f);
            assert!(matches!(get(&s, "k"), Lookup::Corrupt), "length {len}");
            assert!(!s.path("k").exists());
        }
        cleanup(&s);
    }

    #[test]
    fn entry_whose_payload_does_not_decode_is_corrupt_and_removed() {
        let s = store("decode");
        s.put("k", b"not what the cache wrote").unwrap();
        assert!(matches!(s.get("k", |_| None::<()>), Lookup::Corrupt));
        assert!(!s.path("k").exists());
        cleanup(&s);
    }

    #[test]
    fn entry_written_by_concurrent_writers_is_whole() {
        let s = store("concurrent");
        let a = payload(1 << 20, 0x11);
        let b = payload(1 << 20, 0x22);
        let (s, a, b) = (&s, &a, &b);
        std::thread::scope(|scope| {
            for data in [a, b] {
                scope.spawn(move || {
                    for _ in 0..20 {
                        s.put("k", data).unwrap();
                    }
                });
            }
            // A reader meanwhile sees a whole entry or none, never a corrupt one.
            scope.spawn(move || {
                for _ in 0..40 {
                    match get(s, "k") {
                        Lookup::Hit(p) => assert!(p == *a || p == *b),
                        Lookup::Miss => {}
                        Lookup::Corrupt => panic!("a reader saw a partial entry"),
                    }
                }
            });
        });
        let p = get(s, "k").hit().expect("a valid entry");
        assert!(p == *a || p == *b);
        let names: Vec<_> = fs::read_dir(s.dir())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["k.lfthing"], "temp files left behind");
        cleanup(s);
    }

    #[test]
    fn entry_hit_marks_it_used_and_a_miss_does_not() {
        let s = store("used");
        s.put("k", &payload(10, 4)).unwrap();
        let long_ago = SystemTime::UNIX_EPOCH + Duration::from_secs(1_000_000);
        let set = |t: SystemTime| {
            let f = fs::File::options().append(true).open(s.path("k")).unwrap();
            f.set_modified(t).unwrap();
        };
        let modified = || fs::metadata(s.path("k")).unwrap().modified().unwrap();
        set(long_ago);
        // A miss (here: another version) is not a use...
        let stale = other_version(&s, "thing/0");
        assert!(matches!(get(&stale, "k"), Lookup::Miss));
        assert_eq!(modified(), long_ago);
        // ...a hit is.
        let before = SystemTime::now() - Duration::from_secs(1);
        assert!(get(&s, "k").hit().is_some());
        assert!(modified() >= before, "{:?}", modified());
        // A write is a use too.
        set(long_ago);
        s.put("k", &payload(10, 5)).unwrap();
        assert!(modified() >= before);
        cleanup(&s);
    }
}
