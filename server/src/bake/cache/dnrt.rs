//! On-disk cache of DNRT grids, keyed by content: a grid depends on the object alone (mesh,
//! albedo, DNRT settings, seed), so it is reused across scenes and bakes.
//!
//! Owns the key ([`dnrt_key`]: blake3 of code version, every triangle's f64 bits in the object
//! frame, albedo bits, the mesh's own colours — vertex colours, texture coordinates, texture
//! texels — every DNRT setting, seed), the entries' kind ([`ENTRY`]: `<dir>/dnrt/<key>.lfdnrt`)
//! and the payload ([`DnrtGrid::write`]). Framing, atomic writes, verification and marking use
//! are [`crate::bake::cache::entry`]'s: a stale entry is a miss; a corrupt one (or one that
//! does not decode) is deleted and recomputed.
//!
//! The object id stored in a cached grid is replaced by the caller's (same content, any name).

use std::path::PathBuf;

use lightfarm_proto::dnrt_grid::{DnrtCodec, DnrtGrid, DnrtNormals, DnrtPlacement};
use lightfarm_proto::scene::DnrtSettings;
use lightfarm_proto::wire::{Reader, Writer};

use crate::bake::cache::entry::{self, EntryKind, EntryStore};
use crate::bake::scene::mesh_albedo::MeshAlbedo;

/// Bumped whenever the bake's output for the same inputs, or its payload, changes (3: the
/// shared entry framing). In every key, and every entry's version tag.
const CODE_VERSION: &str = "lightfarm-dnrt-3";

/// Where DNRT entries live and their version.
pub const ENTRY: EntryKind = EntryKind {
    subdir: "dnrt",
    extension: "lfdnrt",
    version: CODE_VERSION,
};

/// The content key of one object's grid.
pub fn dnrt_key(
    triangles: &[[[f64; 3]; 3]],
    albedo: [f64; 3],
    mesh_albedo: &MeshAlbedo,
    settings: &DnrtSettings,
    seed: u64,
) -> String {
    let mut h = blake3::Hasher::new();
    h.update(CODE_VERSION.as_bytes());
    h.update(&(triangles.len() as u64).to_le_bytes());
    for x in triangles.iter().flatten().flatten() {
        h.update(&x.to_bits().to_le_bytes());
    }
    for x in albedo {
        h.update(&x.to_bits().to_le_bytes());
    }
    mesh_albedo.hash_into(&mut h);
    h.update(&settings.resolution.to_le_bytes());
    h.update(&settings.sh.to_le_bytes());
    h.update(&settings.extent.to_bits().to_le_bytes());
    h.update(&settings.outer_extent.to_bits().to_le_bytes());
    h.update(&settings.rays.to_le_bytes());
    h.update(&[match settings.codec {
        DnrtCodec::U8 => 0u8,
        DnrtCodec::F16 => 1,
        DnrtCodec::F32 => 2,
    }]);
    h.update(&[match settings.placement {
        DnrtPlacement::Regular => 0u8,
        DnrtPlacement::Quadratic => 1,
    }]);
    h.update(&[match settings.normals {
        DnrtNormals::Intermediate => 0u8,
        DnrtNormals::Convolution => 1,
    }]);
    h.update(&seed.to_le_bytes());
    h.finalize().to_hex().to_string()
}

/// A directory of cached grids.
#[derive(Clone, Debug)]
pub struct DnrtCache {
    store: EntryStore,
}

/// What a lookup found.
pub type DnrtLookup = entry::Lookup<Box<DnrtGrid>>;

impl DnrtCache {
    /// Opens (and creates) `<root>/dnrt`.
    pub fn open(root: impl Into<PathBuf>) -> std::io::Result<DnrtCache> {
        Ok(DnrtCache {
            store: EntryStore::open(root, ENTRY)?,
        })
    }

    /// The cached grid under `key`, renamed to `object`.
    pub fn get(&self, key: &str, object: &str) -> DnrtLookup {
        self.store.get(key, |payload| {
            let mut grid = DnrtGrid::read(&mut Reader::new(payload)).ok()?;
            grid.object = object.to_string();
            Some(Box::new(grid))
        })
    }

    pub fn put(&self, key: &str, grid: &DnrtGrid) -> std::io::Result<()> {
        let mut w = Writer::new();
        grid.write(&mut w);
        self.store.put(key, &w.bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::fs;

    use crate::bake::dnrt::grid::{bake_dnrt_grid, icosphere};
    use crate::bake::scene::mesh_albedo::{SurfaceAlbedo, TriangleAlbedo};

    #[test]
    fn hits_after_put_misses_on_changed_content_and_recovers_from_corruption() {
        let dir = std::env::temp_dir().join(format!("lf-dnrt-cache-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        let cache = DnrtCache::open(&dir).unwrap();
        let tris = icosphere([0.0; 3], 0.3, 1);
        let settings = DnrtSettings {
            resolution: 4,
            rays: 16,
            ..DnrtSettings::default()
        };
        let none = MeshAlbedo::default();
        let key = dnrt_key(&tris, [0.5; 3], &none, &settings, 1);
        assert!(matches!(cache.get(&key, "a"), DnrtLookup::Miss));
        let grid = bake_dnrt_grid("a", &tris, SurfaceAlbedo::Uniform([0.5; 3]), &settings, 1);
        cache.put(&key, &grid).unwrap();
        match cache.get(&key, "b") {
            DnrtLookup::Hit(g) => {
                assert_eq!(g.object, "b");
                assert_eq!(g.values(), grid.values());
            }
            other => panic!("expected a hit, got {other:?}"),
        }
        // Any change of albedo, settings, seed or mesh changes the key.
        let other = DnrtSettings {
            sh: 4,
            ..settings.clone()
        };
        let moved = icosphere([0.0, 0.1, 0.0], 0.3, 1);
        let coloured = MeshAlbedo {
            triangles: vec![
                Some(TriangleAlbedo {
                    vertex: [[0.5, 0.5, 0.4]; 3],
                    texture: None,
                });
                tris.len()
            ],
            textures: vec![],
        };
        for k in [
            dnrt_key(&tris, [0.5, 0.5, 0.4], &none, &settings, 1),
            dnrt_key(&tris, [0.5; 3], &none, &other, 1),
            dnrt_key(&tris, [0.5; 3], &none, &settings, 2),
            dnrt_key(&moved, [0.5; 3], &none, &settings, 1),
            dnrt_key(&tris, [0.5; 3], &coloured, &settings, 1),
        ] {
            assert_ne!(k, key);
        }
        // A corrupt entry is removed and reported.
        let path = cache.store.path(&key);
        let mut bytes = fs::read(&path).unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 0xff;
        fs::write(&path, &bytes).unwrap();
        assert!(matches!(cache.get(&key, "a"), DnrtLookup::Corrupt));
        assert!(!path.exists());
        let _ = fs::remove_dir_all(&dir);
    }
}
