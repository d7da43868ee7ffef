//! On-disk cache of DNRT grids, keyed by content: a grid depends on the object alone (mesh,
//! albedo, DNRT settings, seed), so it is reused across scenes and bakes.
//!
//! Key: blake3 of (code version, every triangle's f64 bits in the object frame, albedo bits,
//! the mesh's own colours — vertex colours, texture coordinates, texture texels — every DNRT
//! setting, seed). Layout: `<dir>/dnrt/<key>.lfdnrt` = 8-byte FNV-1a checksum of the
//! payload, then the payload ([`DnrtGrid::write`]). Writes go to a temp file and are renamed
//! into place; an entry that fails its checksum or does not decode is deleted and recomputed.
//! The object id stored in a cached grid is replaced by the caller's (same content, any name).

use std::fs;
use std::io::Write;
use std::path::PathBuf;

use lightfarm_proto::dnrt_grid::{DnrtCodec, DnrtGrid, DnrtNormals, DnrtPlacement};
use lightfarm_proto::scene::DnrtSettings;
use lightfarm_proto::wire::{checksum, Reader, Writer};

use crate::bake::scene::mesh_albedo::MeshAlbedo;

/// Bumped whenever the bake's output for the same inputs changes.
const CODE_VERSION: &str = "lightfarm-dnrt-2";

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
    dir: PathBuf,
}

/// What a lookup found.
#[derive(Debug)]
pub enum DnrtLookup {
    Hit(Box<DnrtGrid>),
    Miss,
    /// An entry was there but corrupt; it has been removed.
    Corrupt,
}

impl DnrtCache {
    /// Opens (and creates) `<root>/dnrt`.
    pub fn open(root: impl Into<PathBuf>) -> std::io::Result<DnrtCache> {
        let dir = root.into().join("dnrt");
        fs::create_dir_all(&dir)?;
        Ok(DnrtCache { dir })
    }

    fn path(&self, key: &str) -> PathBuf {
        self.dir.join(format!("{key}.lfdnrt"))
    }

    /// Where the grid with this key lives, relative to the operator cache directory.
    pub fn relative_path(key: &str) -> PathBuf {
        PathBuf::from("dnrt").join(format!("{key}.lfdnrt"))
    }

    /// The cached grid under `key`, renamed to `object`.
    pub fn get(&self, key: &str, object: &str) -> DnrtLookup {
        let path = self.path(key);
        let Ok(bytes) = fs::read(&path) else {
            return DnrtLookup::Miss;
        };
        if bytes.len() >= 8
            && u64::from_le_bytes(bytes[..8].try_into().unwrap()) == checksum(&bytes[8..])
        {
            if let Ok(mut grid) = DnrtGrid::read(&mut Reader::new(&bytes[8..])) {
                grid.object = object.to_string();
                crate::bake::cache::shape::mark_used(&path);
                return DnrtLookup::Hit(Box::new(grid));
            }
        }
        let _ = fs::remove_file(&path);
        DnrtLookup::Corrupt
    }

    pub fn put(&self, key: &str, grid: &DnrtGrid) -> std::io::Result<()> {
        let mut w = Writer::new();
        grid.write(&mut w);
        let tmp = self.dir.join(format!(".{key}.{}.tmp", std::process::id()));
        {
            let mut f = fs::File::create(&tmp)?;
            f.write_all(&checksum(&w.bytes).to_le_bytes())?;
            f.write_all(&w.bytes)?;
            f.sync_all()?;
        }
        fs::rename(&tmp, self.path(key))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
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
        let path = cache.path(&key);
        let mut bytes = fs::read(&path).unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 0xff;
        fs::write(&path, &bytes).unwrap();
        assert!(matches!(cache.get(&key, "a"), DnrtLookup::Corrupt));
        assert!(!path.exists());
        let _ = fs::remove_dir_all(&dir);
    }
}
