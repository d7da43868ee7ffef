//! Operator-cache files between a worker's local cache directory (the directory
//! [`crate::bake::cache::shape::ShapeCache`] opens) and the `lightfarm_operators` object store,
//! where each file is stored under its path relative to the cache directory.
//!
//! Invariants:
//! - A downloaded file is written to a temp file and renamed into place, as the engine's own
//!   cache writes are, so a concurrent reader never sees half a file.
//! - A file absent from the object store is skipped, not an error: `unit_inputs` names files a
//!   unit reads *if present* (earlier results it may reuse).
//! - The object store is authoritative: a local copy is replaced by the stored one unless it has
//!   the stored object's SHA-256 (the object store's own digest), in which case nothing moves;
//!   likewise an upload of bytes the store already holds under that name is skipped (a unit run
//!   again writes identical bytes). Cache files are checksummed by the engine, which recomputes
//!   any entry it finds corrupt, and a cache never changes results (an engine invariant), so a
//!   stale or missing file costs time only.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use async_nats::jetstream::object_store::{GetErrorKind, InfoErrorKind, ObjectStore};
use base64::engine::general_purpose::URL_SAFE;
use base64::engine::Engine;
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

/// The object store's digest of `bytes` (`SHA-256=<url-safe base64>`).
pub fn digest(bytes: &[u8]) -> String {
    let sha = ring::digest::digest(&ring::digest::SHA256, bytes);
    format!("SHA-256={}", URL_SAFE.encode(sha.as_ref()))
}

/// The stored digest of `name`; `Ok(None)` when there is no such object.
async fn stored_digest(objects: &ObjectStore, name: &str) -> Result<Option<String>, FarmError> {
    match objects.info(name).await {
        Ok(info) if !info.deleted => Ok(Some(info.digest.unwrap_or_default())),
        Ok(_) => Ok(None),
        Err(e) if e.kind() == InfoErrorKind::NotFound => Ok(None),
        Err(e) => Err(FarmError::nats(format!("look up operator file {name}"), e)),
    }
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
        let target = cache_dir.join(path);
        let Some(stored) = stored_digest(objects, &name).await? else {
            continue;
        };
        if std::fs::read(&target).is_ok_and(|local| digest(&local) == stored) {
            continue;
        }
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

/// Uploads `paths` (relative to `cache_dir`) to the object store, except files it already holds
/// with the same bytes; returns the bytes uploaded.
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
        if stored_digest(objects, &name).await? == Some(digest(&bytes)) {
            continue;
        }
        let mut reader = bytes.as_slice();
        objects
            .put(name.as_str(), &mut reader)
            .await
            .map_err(|e| FarmError::nats(format!("store operator file {name}"), e))?;
        total += bytes.len() as u64;
    }
    Ok(total)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn digest_is_the_object_stores_form() {
        // SHA-256 of nothing, in the object store's `SHA-256=<url-safe base64>` form.
        assert_eq!(
            digest(b""),
            "SHA-256=47DEQpj8HBSa-_TImW-5JCeuQeRkm5NMpJWZG3hSuFU="
        );
    }

    #[test]
    fn object_names_use_slashes() {
        assert_eq!(object_name(Path::new("drt/ab.bin")), "drt/ab.bin");
    }
}
