//! [`FarmStore`]: the [`BlobStore`] of a farm, on the JetStream object store.
//!
//! ```text
//! object store lightfarm_blobs   <kind>/<hash>          the bytes (kind: asset, scene, bundle)
//! KV lightfarm_owners            <team>.<kind>.<hash>   the team may see the blob
//! ```
//!
//! Why the object store and not a shared directory: every farm process already talks to NATS,
//! so the object store needs no shared file system (NFS and its locking, or one volume mounted
//! into every container), and a multi-megabyte bundle moves in 128 KiB chunks over the
//! connection the process already has; JetStream keeps a per-object SHA-256 and replicates with
//! the stream when the NATS server is clustered. The cost is one extra copy through the NATS
//! server per read; `scripts/farm_figures.sh` measures the bytes that cross it per bake.
//!
//! Invariants:
//! - The name is the checksum, as in the embedded store: every read re-hashes the bytes, and a
//!   blob that no longer matches its name is deleted and reported absent.
//! - `put` of a blob already present writes nothing (content addressing makes it idempotent).
//! - Nothing is trimmed: `pin`/`unpin` have nothing to protect against (size the bucket with
//!   JetStream limits if needed). This is a known gap against the embedded store's LRU budget.

use std::sync::Arc;

use futures_util::StreamExt;
use tokio::io::AsyncReadExt;

use super::connection::Farm;
use super::key_token;
use crate::service::store::{content_hash, is_hash, BlobKind, BlobStore, StoreError, StoreStats};

/// Blobs in the farm's object store.
pub struct FarmStore {
    farm: Arc<Farm>,
}

fn object_name(kind: BlobKind, hash: &str) -> String {
    format!("{}/{hash}", kind.name())
}

fn owner_key(team: &str, kind: BlobKind, hash: &str) -> String {
    format!("{}.{}.{hash}", key_token(team), kind.name())
}

fn nats_error(kind: BlobKind, hash: &str, error: impl std::fmt::Display) -> StoreError {
    StoreError::Io {
        kind: kind.name(),
        hash: hash.to_string(),
        source: std::io::Error::other(error.to_string()),
    }
}

impl FarmStore {
    pub fn new(farm: Arc<Farm>) -> FarmStore {
        FarmStore { farm }
    }

    /// Whether the object exists (async, for callers already on the runtime).
    pub async fn exists(&self, kind: BlobKind, hash: &str) -> bool {
        matches!(
            self.farm.blobs.info(object_name(kind, hash)).await,
            Ok(info) if !info.deleted
        )
    }

    /// The bytes, verified (async form of [`BlobStore::get`]).
    pub async fn read(&self, kind: BlobKind, hash: &str) -> Result<Option<Vec<u8>>, StoreError> {
        if !is_hash(hash) {
            return Ok(None);
        }
        let name = object_name(kind, hash);
        let mut object = match self.farm.blobs.get(&name).await {
            Ok(o) => o,
            Err(e) if e.kind() == async_nats::jetstream::object_store::GetErrorKind::NotFound => {
                return Ok(None)
            }
            Err(e) => return Err(nats_error(kind, hash, e)),
        };
        let mut bytes = Vec::new();
        object
            .read_to_end(&mut bytes)
            .await
            .map_err(|e| nats_error(kind, hash, e))?;
        if content_hash(&bytes) != hash {
            tracing::warn!(
                kind = kind.name(),
                %hash,
                "blob does not match its hash: dropped, it will be recomputed"
            );
            let _ = self.farm.blobs.delete(&name).await;
            return Ok(None);
        }
        Ok(Some(bytes))
    }

    /// Stores the bytes unless present (async form of [`BlobStore::put`]).
    pub async fn write(&self, kind: BlobKind, bytes: &[u8]) -> Result<String, StoreError> {
        let hash = content_hash(bytes);
        if self.exists(kind, &hash).await {
            return Ok(hash);
        }
        let mut reader = bytes;
        self.farm
            .blobs
            .put(object_name(kind, &hash).as_str(), &mut reader)
            .await
            .map_err(|e| nats_error(kind, &hash, e))?;
        Ok(hash)
    }

    /// Lets `team` see the blob (async form of [`BlobStore::grant`]).
    pub async fn allow(&self, team: &str, kind: BlobKind, hash: &str) -> Result<(), StoreError> {
        self.farm
            .owners
            .put(owner_key(team, kind, hash), bytes::Bytes::from_static(b"1"))
            .await
            .map(|_| ())
            .map_err(|e| nats_error(kind, hash, e))
    }
}

impl BlobStore for FarmStore {
    fn put(&self, kind: BlobKind, bytes: &[u8]) -> Result<String, StoreError> {
        self.farm.block_on(self.write(kind, bytes))
    }

    fn get(&self, kind: BlobKind, hash: &str) -> Result<Option<Arc<Vec<u8>>>, StoreError> {
        Ok(self.farm.block_on(self.read(kind, hash))?.map(Arc::new))
    }

    fn contains(&self, kind: BlobKind, hash: &str) -> bool {
        is_hash(hash) && self.farm.block_on(self.exists(kind, hash))
    }

    fn grant(&self, team: &str, kind: BlobKind, hash: &str) -> Result<(), StoreError> {
        self.farm.block_on(self.allow(team, kind, hash))
    }

    fn visible(&self, team: &str, kind: BlobKind, hash: &str) -> bool {
        is_hash(hash)
            && self.farm.block_on(async {
                matches!(
                    self.farm.owners.get(owner_key(team, kind, hash)).await,
                    Ok(Some(_))
                )
            })
    }

    fn granted(&self, team: &str, kind: BlobKind) -> Result<Vec<(String, f64)>, StoreError> {
        let prefix = format!("{}.{}.", key_token(team), kind.name());
        self.farm.block_on(async {
            let listing = |e: &dyn std::fmt::Display| StoreError::Io {
                kind: kind.name(),
                hash: String::new(),
                source: std::io::Error::other(format!("listing the owners bucket: {e}")),
            };
            let mut keys = self.farm.owners.keys().await.map_err(|e| listing(&e))?;
            let mut hashes = Vec::new();
            while let Some(key) = keys.next().await {
                let key = key.map_err(|e| listing(&e))?;
                if let Some(hash) = key.strip_prefix(&prefix) {
                    if is_hash(hash) {
                        hashes.push((key.clone(), hash.to_string()));
                    }
                }
            }
            let mut out = Vec::with_capacity(hashes.len());
            for (key, hash) in hashes {
                let at = match self.farm.owners.entry(key).await {
                    Ok(Some(entry)) => (entry.created.unix_timestamp_nanos() as f64) * 1e-9,
                    _ => 0.0,
                };
                out.push((hash, at));
            }
            Ok(out)
        })
    }

    fn pin(&self, _: BlobKind, _: &str) {}

    fn unpin(&self, _: BlobKind, _: &str) {}

    fn stats(&self) -> StoreStats {
        self.farm.block_on(async {
            let mut stats = StoreStats::default();
            let name = format!("OBJ_{}", super::BLOBS_BUCKET);
            if let Ok(mut stream) = self.farm.jetstream.get_stream(&name).await {
                if let Ok(info) = stream.info().await {
                    stats.bytes = info.state.bytes;
                }
            }
            stats
        })
    }
}
