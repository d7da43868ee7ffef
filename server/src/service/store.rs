//! The content-addressed blob store behind the API: uploaded assets, canonical scenes and baked
//! bundles, each named by the BLAKE3 hash of its bytes, plus which team may see which blob.
//!
//! [`BlobStore`] is the seam a distributed backend plugs into; [`DiskStore`] is the embedded one:
//!
//! ```text
//! <data>/blobs/<kind>/<hash>        the bytes (kind: asset, scene, bundle)
//! <data>/owners/<team>/<kind>/<hash> empty marker: the team may see the blob
//! <data>/tmp/                        writes in flight (emptied at open)
//! ```
//!
//! Invariants:
//! - A blob file is complete or absent: bytes go to `tmp/`, are synced, then renamed into place.
//! - The name is the checksum: every read re-hashes the bytes; a blob that no longer matches its
//!   name (disk damage, a stray write) is deleted, counted and reported as absent, so the caller
//!   recomputes it. Nothing that fails the check is ever served.
//! - Recently read blobs are kept in memory, verified, up to [`HOT_BYTES`]: the store is
//!   immutable per name, so a verified copy stays right, and a popular bundle is neither re-read
//!   nor re-hashed per download.
//! - The store is trimmed least-recently-used (reads and writes count as use; the order survives
//!   restarts through file modification times) to a byte budget; pinned blobs (inputs of queued
//!   or running bakes) are never trimmed.

use std::collections::HashMap;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::SystemTime;

/// Bytes of verified blobs kept in memory.
pub const HOT_BYTES: u64 = 256 << 20;

/// What a blob is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum BlobKind {
    Asset,
    Scene,
    Bundle,
}

impl BlobKind {
    pub const ALL: [BlobKind; 3] = [BlobKind::Asset, BlobKind::Scene, BlobKind::Bundle];

    pub fn name(self) -> &'static str {
        match self {
            BlobKind::Asset => "asset",
            BlobKind::Scene => "scene",
            BlobKind::Bundle => "bundle",
        }
    }
}

/// A store failure (I/O), naming the blob.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("store: {kind} {hash}: {source}")]
    Io {
        kind: &'static str,
        hash: String,
        source: std::io::Error,
    },
    #[error("store: {0}")]
    Open(std::io::Error),
}

/// Totals for `/metrics`.
#[derive(Clone, Debug, Default)]
pub struct StoreStats {
    pub bytes: u64,
    pub blobs: u64,
    pub corrupt_dropped: u64,
    pub trimmed: u64,
}

/// The lowercase hex BLAKE3 hash that names `bytes`.
pub fn content_hash(bytes: &[u8]) -> String {
    blake3::hash(bytes).to_hex().to_string()
}

/// Whether `s` looks like a content hash (64 lowercase hex digits); anything else is never a
/// file name in the store.
pub fn is_hash(s: &str) -> bool {
    s.len() == 64
        && s.bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// Blobs by content hash, with per-team visibility.
pub trait BlobStore: Send + Sync + 'static {
    /// Stores `bytes` (idempotent) and returns their hash.
    fn put(&self, kind: BlobKind, bytes: &[u8]) -> Result<String, StoreError>;
    /// The bytes, verified against their hash; `None` when absent or found corrupt (dropped).
    fn get(&self, kind: BlobKind, hash: &str) -> Result<Option<Arc<Vec<u8>>>, StoreError>;
    /// Whether the blob is present (not verified).
    fn contains(&self, kind: BlobKind, hash: &str) -> bool;
    /// Lets `team` see the blob.
    fn grant(&self, team: &str, kind: BlobKind, hash: &str) -> Result<(), StoreError>;
    /// Whether `team` may see the blob.
    fn visible(&self, team: &str, kind: BlobKind, hash: &str) -> bool;
    /// Every blob of `kind` the team may see, with when it was granted (Unix seconds), in no
    /// particular order.
    fn granted(&self, team: &str, kind: BlobKind) -> Result<Vec<(String, f64)>, StoreError>;
    /// Keeps the blob from being trimmed until as many `unpin`s.
    fn pin(&self, kind: BlobKind, hash: &str);
    fn unpin(&self, kind: BlobKind, hash: &str);
    fn stats(&self) -> StoreStats;
}

#[derive(Clone, Copy, Debug)]
struct Entry {
    bytes: u64,
    /// Larger is more recent.
    last_use: u128,
}

/// Verified blobs in memory, least recently used evicted first.
#[derive(Default)]
struct Hot {
    blobs: HashMap<(BlobKind, String), (Arc<Vec<u8>>, u64)>,
    bytes: u64,
    clock: u64,
}

impl Hot {
    fn get(&mut self, key: &(BlobKind, String)) -> Option<Arc<Vec<u8>>> {
        self.clock += 1;
        let clock = self.clock;
        self.blobs.get_mut(key).map(|(b, used)| {
            *used = clock;
            b.clone()
        })
    }

    fn insert(&mut self, key: (BlobKind, String), blob: Arc<Vec<u8>>) {
        let len = blob.len() as u64;
        if len > HOT_BYTES / 4 {
            return;
        }
        while self.bytes + len > HOT_BYTES {
            let Some(oldest) = self
                .blobs
                .iter()
                .min_by_key(|(_, (_, used))| *used)
                .map(|(k, _)| k.clone())
            else {
                break;
            };
            self.remove(&oldest);
        }
        self.clock += 1;
        if let Some((old, _)) = self.blobs.insert(key, (blob, self.clock)) {
            self.bytes -= old.len() as u64;
        }
        self.bytes += len;
    }

    fn remove(&mut self, key: &(BlobKind, String)) {
        if let Some((b, _)) = self.blobs.remove(key) {
            self.bytes -= b.len() as u64;
        }
    }
}

#[derive(Default)]
struct Index {
    entries: HashMap<(BlobKind, String), Entry>,
    pins: HashMap<(BlobKind, String), u32>,
    total: u64,
}

/// The embedded, on-disk [`BlobStore`].
pub struct DiskStore {
    root: PathBuf,
    budget: u64,
    index: Mutex<Index>,
    hot: Mutex<Hot>,
    corrupt_dropped: AtomicU64,
    trimmed: AtomicU64,
    tmp_counter: AtomicU64,
}

fn now_nanos() -> u128 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0)
}

impl DiskStore {
    /// Opens (creating) the store under `root`, trimmed to `budget` bytes.
    pub fn open(root: &Path, budget: u64) -> Result<DiskStore, StoreError> {
        let tmp = root.join("tmp");
        if tmp.exists() {
            fs::remove_dir_all(&tmp).map_err(StoreError::Open)?;
        }
        fs::create_dir_all(&tmp).map_err(StoreError::Open)?;
        let mut index = Index::default();
        for kind in BlobKind::ALL {
            let dir = root.join("blobs").join(kind.name());
            fs::create_dir_all(&dir).map_err(StoreError::Open)?;
            for entry in fs::read_dir(&dir).map_err(StoreError::Open)? {
                let entry = entry.map_err(StoreError::Open)?;
                let name = entry.file_name().to_string_lossy().to_string();
                if !is_hash(&name) {
                    continue;
                }
                let meta = entry.metadata().map_err(StoreError::Open)?;
                let last_use = meta
                    .modified()
                    .ok()
                    .and_then(|t| t.duration_since(SystemTime::UNIX_EPOCH).ok())
                    .map(|d| d.as_nanos())
                    .unwrap_or(0);
                index.total += meta.len();
                index.entries.insert(
                    (kind, name),
                    Entry {
                        bytes: meta.len(),
                        last_use,
                    },
                );
            }
        }
        Ok(DiskStore {
            root: root.to_path_buf(),
            budget,
            index: Mutex::new(index),
            hot: Mutex::new(Hot::default()),
            corrupt_dropped: AtomicU64::new(0),
            trimmed: AtomicU64::new(0),
            tmp_counter: AtomicU64::new(0),
        })
    }

    fn blob_path(&self, kind: BlobKind, hash: &str) -> PathBuf {
        self.root.join("blobs").join(kind.name()).join(hash)
    }

    fn marker_path(&self, team: &str, kind: BlobKind, hash: &str) -> PathBuf {
        self.root
            .join("owners")
            .join(team)
            .join(kind.name())
            .join(hash)
    }

    fn io(kind: BlobKind, hash: &str) -> impl FnOnce(std::io::Error) -> StoreError + '_ {
        move |source| StoreError::Io {
            kind: kind.name(),
            hash: hash.to_string(),
            source,
        }
    }

    fn touch(&self, kind: BlobKind, hash: &str) {
        let mut index = self.index.lock().unwrap();
        if let Some(e) = index.entries.get_mut(&(kind, hash.to_string())) {
            e.last_use = now_nanos();
        }
        drop(index);
        // The order survives a restart; failing to record it only loses recency.
        if let Ok(f) = fs::File::options()
            .write(true)
            .open(self.blob_path(kind, hash))
        {
            let _ = f.set_modified(SystemTime::now());
        }
    }

    fn forget(&self, kind: BlobKind, hash: &str) {
        self.hot.lock().unwrap().remove(&(kind, hash.to_string()));
        let mut index = self.index.lock().unwrap();
        if let Some(e) = index.entries.remove(&(kind, hash.to_string())) {
            index.total -= e.bytes;
        }
    }

    /// Deletes least-recently-used unpinned blobs until the total is within budget.
    fn trim(&self) {
        let mut index = self.index.lock().unwrap();
        if index.total <= self.budget {
            return;
        }
        let mut candidates: Vec<((BlobKind, String), Entry)> = index
            .entries
            .iter()
            .filter(|(k, _)| !index.pins.contains_key(*k))
            .map(|(k, e)| (k.clone(), *e))
            .collect();
        candidates.sort_by_key(|(_, e)| e.last_use);
        for ((kind, hash), e) in candidates {
            if index.total <= self.budget {
                break;
            }
            if fs::remove_file(self.blob_path(kind, &hash)).is_ok() {
                self.hot.lock().unwrap().remove(&(kind, hash.clone()));
                index.entries.remove(&(kind, hash.clone()));
                index.total -= e.bytes;
                self.trimmed.fetch_add(1, Ordering::Relaxed);
                tracing::info!(kind = kind.name(), %hash, bytes = e.bytes, "trimmed from the store");
            }
        }
    }
}

impl BlobStore for DiskStore {
    fn put(&self, kind: BlobKind, bytes: &[u8]) -> Result<String, StoreError> {
        let hash = content_hash(bytes);
        let path = self.blob_path(kind, &hash);
        if path.exists() {
            self.touch(kind, &hash);
            return Ok(hash);
        }
        let tmp = self.root.join("tmp").join(format!(
            "{hash}.{}.{}",
            std::process::id(),
            self.tmp_counter.fetch_add(1, Ordering::Relaxed)
        ));
        let write = || -> std::io::Result<()> {
            let mut f = fs::File::create(&tmp)?;
            f.write_all(bytes)?;
            f.sync_all()?;
            drop(f);
            fs::rename(&tmp, &path)
        };
        if let Err(e) = write() {
            let _ = fs::remove_file(&tmp);
            return Err(Self::io(kind, &hash)(e));
        }
        {
            let mut index = self.index.lock().unwrap();
            let old = index.entries.insert(
                (kind, hash.clone()),
                Entry {
                    bytes: bytes.len() as u64,
                    last_use: now_nanos(),
                },
            );
            index.total += bytes.len() as u64;
            if let Some(old) = old {
                index.total -= old.bytes;
            }
        }
        // Never trim what was just written: pin it for the trim.
        self.pin(kind, &hash);
        self.trim();
        self.unpin(kind, &hash);
        Ok(hash)
    }

    fn get(&self, kind: BlobKind, hash: &str) -> Result<Option<Arc<Vec<u8>>>, StoreError> {
        if !is_hash(hash) {
            return Ok(None);
        }
        let key = (kind, hash.to_string());
        if let Some(blob) = self.hot.lock().unwrap().get(&key) {
            let mut index = self.index.lock().unwrap();
            if let Some(e) = index.entries.get_mut(&key) {
                // Recency in memory only: the file's time is refreshed on disk reads.
                e.last_use = now_nanos();
                return Ok(Some(blob));
            }
        }
        let path = self.blob_path(kind, hash);
        let bytes = match fs::read(&path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                self.forget(kind, hash);
                return Ok(None);
            }
            Err(e) => return Err(Self::io(kind, hash)(e)),
        };
        if content_hash(&bytes) != hash {
            tracing::warn!(
                kind = kind.name(),
                %hash,
                "blob does not match its hash: dropped, it will be recomputed"
            );
            let _ = fs::remove_file(&path);
            self.forget(kind, hash);
            self.corrupt_dropped.fetch_add(1, Ordering::Relaxed);
            return Ok(None);
        }
        self.touch(kind, hash);
        let blob = Arc::new(bytes);
        self.hot.lock().unwrap().insert(key, blob.clone());
        Ok(Some(blob))
    }

    fn contains(&self, kind: BlobKind, hash: &str) -> bool {
        is_hash(hash) && self.blob_path(kind, hash).exists()
    }

    fn grant(&self, team: &str, kind: BlobKind, hash: &str) -> Result<(), StoreError> {
        let path = self.marker_path(team, kind, hash);
        if path.exists() {
            return Ok(());
        }
        let dir = path.parent().expect("marker has a parent");
        fs::create_dir_all(dir).map_err(Self::io(kind, hash))?;
        fs::write(&path, b"").map_err(Self::io(kind, hash))
    }

    fn visible(&self, team: &str, kind: BlobKind, hash: &str) -> bool {
        is_hash(hash) && self.marker_path(team, kind, hash).exists()
    }

    fn granted(&self, team: &str, kind: BlobKind) -> Result<Vec<(String, f64)>, StoreError> {
        let dir = self.root.join("owners").join(team).join(kind.name());
        let entries = match fs::read_dir(&dir) {
            Ok(entries) => entries,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
            Err(e) => return Err(StoreError::Open(e)),
        };
        let mut out = Vec::new();
        for entry in entries {
            let entry = entry.map_err(StoreError::Open)?;
            let name = entry.file_name().to_string_lossy().to_string();
            if !is_hash(&name) {
                continue;
            }
            let at = entry
                .metadata()
                .and_then(|m| m.modified())
                .ok()
                .and_then(|t| t.duration_since(SystemTime::UNIX_EPOCH).ok())
                .map_or(0.0, |d| d.as_secs_f64());
            out.push((name, at));
        }
        Ok(out)
    }

    fn pin(&self, kind: BlobKind, hash: &str) {
        let mut index = self.index.lock().unwrap();
        *index.pins.entry((kind, hash.to_string())).or_insert(0) += 1;
    }

    fn unpin(&self, kind: BlobKind, hash: &str) {
        let mut index = self.index.lock().unwrap();
        let key = (kind, hash.to_string());
        if let Some(n) = index.pins.get_mut(&key) {
            *n -= 1;
            if *n == 0 {
                index.pins.remove(&key);
            }
        }
    }

    fn stats(&self) -> StoreStats {
        let index = self.index.lock().unwrap();
        StoreStats {
            bytes: index.total,
            blobs: index.entries.len() as u64,
            corrupt_dropped: self.corrupt_dropped.load(Ordering::Relaxed),
            trimmed: self.trimmed.load(Ordering::Relaxed),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_root(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("lightfarm-store-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn round_trip_and_visibility() {
        let root = temp_root("rt");
        let store = DiskStore::open(&root, 1 << 30).unwrap();
        let h = store.put(BlobKind::Bundle, b"hello").unwrap();
        assert_eq!(h, content_hash(b"hello"));
        assert_eq!(
            store.get(BlobKind::Bundle, &h).unwrap().unwrap().as_slice(),
            b"hello"
        );
        assert!(store.get(BlobKind::Scene, &h).unwrap().is_none());
        assert!(!store.visible("a", BlobKind::Bundle, &h));
        store.grant("a", BlobKind::Bundle, &h).unwrap();
        assert!(store.visible("a", BlobKind::Bundle, &h));
        assert!(!store.visible("b", BlobKind::Bundle, &h));
        assert!(store
            .get(BlobKind::Bundle, "../../etc/passwd")
            .unwrap()
            .is_none());
        // Reopened, the blob and the grant are still there.
        drop(store);
        let store = DiskStore::open(&root, 1 << 30).unwrap();
        assert_eq!(store.stats().blobs, 1);
        assert!(store.visible("a", BlobKind::Bundle, &h));
        let _ = fs::remove_dir_all(&root);
    }

    #[test]
    fn corrupt_blob_is_dropped_not_served() {
        let root = temp_root("corrupt");
        let store = DiskStore::open(&root, 1 << 30).unwrap();
        let h = store.put(BlobKind::Bundle, b"the bundle bytes").unwrap();
        fs::write(store.blob_path(BlobKind::Bundle, &h), b"the bundle bytez").unwrap();
        assert!(store.get(BlobKind::Bundle, &h).unwrap().is_none());
        assert!(!store.contains(BlobKind::Bundle, &h));
        assert_eq!(store.stats().corrupt_dropped, 1);
        assert_eq!(store.stats().bytes, 0);
        // Recomputed: stored again under the same name.
        store.put(BlobKind::Bundle, b"the bundle bytes").unwrap();
        assert!(store.get(BlobKind::Bundle, &h).unwrap().is_some());
        let _ = fs::remove_dir_all(&root);
    }

    #[test]
    fn trims_least_recently_used_and_keeps_pins() {
        let root = temp_root("trim");
        let store = DiskStore::open(&root, 25).unwrap();
        let a = store.put(BlobKind::Bundle, &[1u8; 10]).unwrap();
        let b = store.put(BlobKind::Bundle, &[2u8; 10]).unwrap();
        store.pin(BlobKind::Bundle, &a);
        store.get(BlobKind::Bundle, &b).unwrap();
        // a is older but pinned; b is the least recent unpinned one.
        let c = store.put(BlobKind::Bundle, &[3u8; 10]).unwrap();
        assert!(store.contains(BlobKind::Bundle, &a));
        assert!(!store.contains(BlobKind::Bundle, &b));
        assert!(store.contains(BlobKind::Bundle, &c));
        assert_eq!(store.stats().trimmed, 1);
        assert_eq!(store.stats().bytes, 20);
        let _ = fs::remove_dir_all(&root);
    }
}
