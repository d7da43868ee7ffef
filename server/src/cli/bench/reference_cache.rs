//! The on-disk cache of brute-force reference results for `lightfarm bench`, keyed by content.
//!
//! Key = BLAKE3 of (reference solver version, the scene's blocks, clutter and dynamic objects
//! as JSON, texels per face, the bytes of every mesh the scene names, the light set as JSON,
//! rays per texel, seed, and the bounce count unless it is one). One bounce hashes exactly as
//! before bounces existed (the solver's one-bounce output is unchanged), so one-bounce entries
//! of older caches keep serving; every other count adds its name, so a one-bounce and an
//! all-bounce reference of the same scene, lights, rays and seed never share a key. Nothing else of the scene (name, other settings, light regions)
//! enters, so adding a setting elsewhere never invalidates the cache. Entries are zstd-compressed JSON of
//! [`CachedReference`] written to a temp file and renamed; an entry that does not decode is
//! recomputed.
//!
//! Invariant: the key depends only on what the reference result depends on, so a rerun (or a
//! sweep over rays per texel, tolerance or codec at the same texels per face) reuses entries.
//! Bump [`REFERENCE_SOLVER_VERSION`] whenever `bake/reference.rs` changes its output.

use std::path::{Path, PathBuf};

use lightfarm_proto::bounces::BounceCount;
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::ResultFile;
use lightfarm_proto::scene::Scene;
use serde::{Deserialize, Serialize};

use crate::cli::write_atomic;

/// Version of the reference solver's output; part of every key.
pub const REFERENCE_SOLVER_VERSION: u32 = 1;

/// One cached reference run: its result and how long it took when it was computed.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CachedReference {
    pub seconds: f64,
    pub result: ResultFile,
}

/// Content key of a reference run (hex BLAKE3). `mesh_bytes` are the contents of the meshes
/// the scene names, in scene order (clutter, then dynamic objects); `bounces` is the bounce
/// count the reference sums.
pub fn reference_key(
    scene: &Scene,
    mesh_bytes: &[Vec<u8>],
    lights: &LightSet,
    rays: u32,
    seed: u64,
    bounces: BounceCount,
) -> String {
    let mut hasher = blake3::Hasher::new();
    hasher.update(b"lightfarm-bench-reference\0");
    hasher.update(&REFERENCE_SOLVER_VERSION.to_le_bytes());
    // What `Geometry::from_scene` and the reference read: the objects and the texel count.
    let scene_json = serde_json::to_vec(&(
        &scene.blocks,
        &scene.clutter,
        &scene.dynamic,
        scene.settings.texels_per_face,
    ))
    .expect("a scene serialises");
    hasher.update(&(scene_json.len() as u64).to_le_bytes());
    hasher.update(&scene_json);
    for mesh in mesh_bytes {
        hasher.update(&(mesh.len() as u64).to_le_bytes());
        hasher.update(mesh);
    }
    let lights_json = serde_json::to_vec(lights).expect("a light set serialises");
    hasher.update(&(lights_json.len() as u64).to_le_bytes());
    hasher.update(&lights_json);
    hasher.update(&rays.to_le_bytes());
    hasher.update(&seed.to_le_bytes());
    if bounces != BounceCount::ONE {
        let name = bounces.to_string();
        hasher.update(b"\0bounces\0");
        hasher.update(&(name.len() as u64).to_le_bytes());
        hasher.update(name.as_bytes());
    }
    hasher.finalize().to_hex().to_string()
}

/// The bytes of every mesh file a scene names (clutter meshes, then dynamic objects).
pub fn mesh_bytes(scene: &Scene, scene_dir: &Path) -> anyhow::Result<Vec<Vec<u8>>> {
    let paths = scene
        .clutter
        .iter()
        .filter_map(|c| c.mesh.as_deref())
        .chain(scene.dynamic.iter().map(|d| d.mesh.as_str()));
    paths
        .map(|p| {
            let path = scene_dir.join(p);
            std::fs::read(&path).map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))
        })
        .collect()
}

/// A directory of cached reference results.
pub struct ReferenceCache {
    dir: PathBuf,
}

impl ReferenceCache {
    pub fn open(dir: &Path) -> anyhow::Result<ReferenceCache> {
        std::fs::create_dir_all(dir)
            .map_err(|e| anyhow::anyhow!("cannot create {}: {e}", dir.display()))?;
        Ok(ReferenceCache {
            dir: dir.to_path_buf(),
        })
    }

    fn path(&self, key: &str) -> PathBuf {
        self.dir.join(format!("{key}.json.zst"))
    }

    /// The entry under `key`, or None when it is missing or does not decode.
    pub fn get(&self, key: &str) -> Option<CachedReference> {
        let compressed = std::fs::read(self.path(key)).ok()?;
        let json = zstd::decode_all(compressed.as_slice()).ok()?;
        serde_json::from_slice(&json).ok()
    }

    pub fn put(&self, key: &str, entry: &CachedReference) -> anyhow::Result<()> {
        let json = serde_json::to_vec(entry)?;
        let compressed = zstd::encode_all(json.as_slice(), 3)?;
        write_atomic(&self.path(key), &compressed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::lights::{Light, LightKind};

    const ONE: BounceCount = BounceCount::ONE;

    fn cornell() -> Scene {
        Scene::from_json(include_str!("../../../../scenes/cornell/scene.json")).unwrap()
    }

    fn lights() -> LightSet {
        LightSet {
            lights: vec![Light {
                kind: LightKind::Point,
                position: [2.75, 5.2, 2.75],
                intensity: [10.0; 3],
            }],
            poses: vec![],
        }
    }

    /// The key is a pinned value: a change here silently invalidates (or, worse, wrongly
    /// reuses) every cached reference, so it must be deliberate.
    #[test]
    fn key_is_stable_and_depends_only_on_what_the_reference_reads() {
        let scene = cornell();
        let key = reference_key(&scene, &[], &lights(), 4096, 1, ONE);
        assert_eq!(key, reference_key(&scene, &[], &lights(), 4096, 1, ONE));
        assert_eq!(key, PINNED_CORNELL_KEY);
        // Settings the reference does not read leave the key alone.
        let mut other = scene.clone();
        other.settings.rays_per_texel = 64;
        other.settings.tolerance = 0.1;
        other.name = "renamed".into();
        assert_eq!(key, reference_key(&other, &[], &lights(), 4096, 1, ONE));
        // What it reads changes it.
        let mut finer = scene.clone();
        finer.settings.texels_per_face = 32;
        assert_ne!(key, reference_key(&finer, &[], &lights(), 4096, 1, ONE));
        assert_ne!(key, reference_key(&scene, &[], &lights(), 2048, 1, ONE));
        assert_ne!(key, reference_key(&scene, &[], &lights(), 4096, 2, ONE));
        assert_ne!(
            key,
            reference_key(&scene, &[vec![1]], &lights(), 4096, 1, ONE)
        );
        let mut moved = scene.clone();
        moved.clutter[0].albedo[0] = 0.5;
        assert_ne!(key, reference_key(&moved, &[], &lights(), 4096, 1, ONE));
        let mut brighter = lights();
        brighter.lights[0].intensity[0] = 11.0;
        assert_ne!(key, reference_key(&scene, &[], &brighter, 4096, 1, ONE));
    }

    /// The one-bounce key of cornell, unchanged since before bounces existed (so one-bounce
    /// entries of older caches keep serving).
    const PINNED_CORNELL_KEY: &str =
        "768c23954a04433f8a7f45fecfe85d8f3070e5907f64580dcaac66a463ba485b";
    /// The all-bounce key of the same scene, lights, rays and seed.
    const PINNED_CORNELL_ALL_BOUNCES_KEY: &str =
        "1617d7cc3a22f480447f9c3870e85bfc38e88c96095d47630b55f5694f440557";

    /// A one-bounce and an all-bounce reference of the same scene, lights, rays and seed are
    /// different results and must never share an entry; nor may two fixed counts.
    #[test]
    fn the_bounce_count_separates_keys() {
        let scene = cornell();
        let key = |bounces| reference_key(&scene, &[], &lights(), 4096, 1, bounces);
        let one = key(ONE);
        let all = key(BounceCount::All);
        assert_eq!(one, PINNED_CORNELL_KEY);
        assert_eq!(all, PINNED_CORNELL_ALL_BOUNCES_KEY);
        let keys = [
            one,
            all,
            key(BounceCount::Fixed(2)),
            key(BounceCount::Fixed(3)),
            key(BounceCount::Fixed(12)),
        ];
        for (i, a) in keys.iter().enumerate() {
            for b in &keys[i + 1..] {
                assert_ne!(a, b);
            }
        }
        // A cached one-bounce entry is not served for an all-bounce request, and back.
        let dir = std::env::temp_dir().join(format!("lf-bench-refbounces-{}", std::process::id()));
        let cache = ReferenceCache::open(&dir).unwrap();
        let entry = CachedReference {
            seconds: 2.5,
            result: ResultFile { texels: vec![] },
        };
        cache.put(&keys[0], &entry).unwrap();
        assert_eq!(cache.get(&keys[0]).unwrap().seconds, 2.5);
        assert!(cache.get(&keys[1]).is_none());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn entries_round_trip_and_corrupt_entries_read_as_missing() {
        let dir = std::env::temp_dir().join(format!("lf-bench-refcache-{}", std::process::id()));
        let cache = ReferenceCache::open(&dir).unwrap();
        let entry = CachedReference {
            seconds: 1.5,
            result: ResultFile { texels: vec![] },
        };
        cache.put("k", &entry).unwrap();
        assert_eq!(cache.get("k").unwrap().seconds, 1.5);
        std::fs::write(cache.path("k"), b"not zstd").unwrap();
        assert!(cache.get("k").is_none());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
