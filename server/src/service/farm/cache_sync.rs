//! Operator-cache files between a worker's local cache directory (the directory
//! [`crate::bake::shape_cache::ShapeCache`] opens) and the `lightfarm_operators` object store,
//! where each file is stored under its path relative to the cache directory.
//!
//! Invariants:
//! - A downloaded file is written to a temp file and renamed into place, as the engine's own
//!   cache writes are, so a concurrent reader never sees half a file.
//! - A file absent from the object store is skipped, not an error: `unit_inputs` names files a
//!   unit reads *if present* (earlier results it may reuse).
//! - The object store is authoritative: a local copy is replaced by the stored one. Cache files
//!   are checksummed by the engine, which recomputes any entry it finds corrupt, and a cache
//!   never changes results (an engine invariant), so a stale or missing file costs time only.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use async_nats::jetstream::object_store::{GetErrorKind, ObjectStore};
use tokio::io::AsyncReadExt;

use super::FarmError;

static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// The object name of a cache file (its relative path with `/` separators).
pub fn object_name(path: &Path) -> String {
    path.components()
        .map(|c| c.as_os_str().to_string_lossy())
        .collect::<Vec<_>>()
        .join("/")
}

/// Downloads the stored ones among `paths` into `cache_dir`; returns the bytes downloaded.
pub async fn download(
    objects: &ObjectStore,
    cache_dir: &Path,
    paths: &[PathBuf],
) -> Result<u64, FarmError> {
    let mut total = 0;
    for path in paths {
        let name = object_name(path);
        let mut object = match objects.get(&name).await {
            Ok(o) => o,
            Err(e) if e.kind() == GetErrorKind::NotFound => continue,
            Err(e) => return Err(FarmError::nats(format!("fetch operator file {name}"), e)),
        };
        let mut bytes = Vec::new();
        object
            .read_to_end(&mut bytes)
            .await
            .map_err(|e| FarmError::nats(format!("read operator file {name}"), e))?;
        let target = cache_dir.join(path);
        let write = || -> std::io::Result<()> {
            let dir = target.parent().unwrap_or(cache_dir);
            std::fs::create_dir_all(dir)?;
            let tmp = dir.join(format!(
                ".farm-{}-{}.tmp",
                std::process::id(),
                TEMP_COUNTER.fetch_add(1, Ordering::Relaxed)
            ));
            std::fs::write(&tmp, &bytes)?;
            std::fs::rename(&tmp, &target)
        };
        write().map_err(|e| FarmError::nats(format!("write {}", target.display()), e))?;
        total += bytes.len() as u64;
    }
    Ok(total)
}

/// Uploads `paths` (relative to `cache_dir`) to the object store; returns the bytes uploaded.
pub async fn upload(
    objects: &ObjectStore,
    cache_dir: &Path,
    paths: &[PathBuf],
) -> Result<u64, FarmError> {
    let mut total = 0;
    for path in paths {
        let name = object_name(path);
        let source = cache_dir.join(path);
        let bytes = std::fs::read(&source)
            .map_err(|e| FarmError::nats(format!("read {}", source.display()), e))?;
        let mut reader = bytes.as_slice();
        objects
            .put(name.as_str(), &mut reader)
            .await
            .map_err(|e| FarmError::nats(format!("store operator file {name}"), e))?;
        total += bytes.len() as u64;
    }
    Ok(total)
}
