//! On-disk memo of whole encoded bundles, keyed by everything a bake reads: a rebake whose
//! inputs did not change (a CI job baking the same level again, an editor re-saving it) hands
//! back the bytes the bake gave before instead of rerunning it (issue 19: a rebake with nothing
//! changed).
//!
//! The key ([`MemoKey`], blake3) covers, in order:
//! - `CODE_VERSION` and the engine's build: the running executable's length and modification
//!   time (as `ccache`'s default compiler check does), so any rebuild of the engine misses;
//! - the scene as parsed (its canonical JSON: settings included), and the bake's options (the
//!   dense operator, the transport and codec overrides);
//! - the bytes of every file the scene's meshes read: each mesh file, and for glTF the external
//!   buffers and images it names (relative URIs; `data:` URIs are in the file already).
//!
//! When one of those cannot be read there is no key and the bake runs as usual (and reports
//! the error the bake finds).
//!
//! Owns the entries' kind ([`ENTRY`]: `<dir>/bundles/<key>.lfbundle`); the payload is the
//! encoded bundle, whole. Framing, atomic writes, verification and marking use are
//! [`crate::bake::cache::entry`]'s: a corrupt entry is deleted and missed, so the bake runs.
//!
//! Invariant: a hit returns the bytes a bake of the same inputs by the same build wrote; the
//! bake is deterministic (bit-identical at any thread count), so they are the bytes it would
//! write now.

use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use lightfarm_proto::scene::{BundleCodec, Scene, Transport};

use crate::bake::cache::entry::{EntryKind, EntryStore};

/// Bumped whenever the key's contents or the payload change.
const CODE_VERSION: &str = "lightfarm-bundle-memo-1";

/// Where memoised bundles live and their version.
pub const ENTRY: EntryKind = EntryKind {
    subdir: "bundles",
    extension: "lfbundle",
    version: CODE_VERSION,
};

/// What a bake is asked beyond its scene (the CLI's `bake` flags).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MemoOptions {
    pub full: bool,
    pub transport: Option<Transport>,
    pub codec: Option<BundleCodec>,
}

/// A memo key (hex blake3).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MemoKey(pub String);

/// The bundle memo in an operator cache directory.
#[derive(Clone, Debug)]
pub struct BundleMemo {
    store: EntryStore,
}

impl BundleMemo {
    /// Opens (and creates) `<dir>/bundles`.
    pub fn open(dir: &Path) -> std::io::Result<BundleMemo> {
        Ok(BundleMemo {
            store: EntryStore::open(dir, ENTRY)?,
        })
    }

    /// The key of baking `scene` (its files relative to `scene_dir`) with `options` by this
    /// build; `None` when an input cannot be read.
    pub fn key(scene: &Scene, scene_dir: &Path, options: &MemoOptions) -> Option<MemoKey> {
        let mut h = blake3::Hasher::new();
        h.update(CODE_VERSION.as_bytes());
        h.update(&build_identity()?);
        let json = serde_json::to_vec(scene).ok()?;
        h.update(&(json.len() as u64).to_le_bytes());
        h.update(&json);
        h.update(format!("{options:?}").as_bytes());
        for file in mesh_files(scene, scene_dir)? {
            let bytes = std::fs::read(&file).ok()?;
            h.update(&(bytes.len() as u64).to_le_bytes());
            h.update(&bytes);
        }
        Some(MemoKey(h.finalize().to_hex().to_string()))
    }

    /// The bundle memoised under `key`, if any (a corrupt entry is deleted and missed).
    pub fn get(&self, key: &MemoKey) -> Option<Vec<u8>> {
        self.store
            .get(&key.0, |payload| Some(payload.to_vec()))
            .hit()
    }

    /// Where the entry of `key` lives.
    pub fn path(&self, key: &MemoKey) -> PathBuf {
        self.store.path(&key.0)
    }

    /// Memoises `bundle` under `key`.
    pub fn put(&self, key: &MemoKey, bundle: &[u8]) -> std::io::Result<()> {
        self.store.put(&key.0, bundle)
    }
}

/// The running engine's build: its executable's length and modification time (as `ccache`'s
/// default compiler check), so any rebuild gives another; None when it cannot be read.
pub(crate) fn build_identity() -> Option<Vec<u8>> {
    let exe = std::env::current_exe().ok()?.metadata().ok()?;
    let built = exe.modified().ok()?.duration_since(UNIX_EPOCH).ok()?;
    let mut id = exe.len().to_le_bytes().to_vec();
    id.extend_from_slice(&built.as_nanos().to_le_bytes());
    Some(id)
}

/// Every file the scene's meshes read, in scene order: each mesh file, then for glTF its
/// external buffers and images. `None` when a glTF file cannot be parsed.
fn mesh_files(scene: &Scene, scene_dir: &Path) -> Option<Vec<PathBuf>> {
    let meshes = scene
        .clutter
        .iter()
        .filter_map(|c| c.mesh.as_deref())
        .chain(scene.dynamic.iter().map(|d| d.mesh.as_str()));
    let mut files = Vec::new();
    for mesh in meshes {
        let path = scene_dir.join(mesh);
        let lower = mesh.to_ascii_lowercase();
        if lower.ends_with(".gltf") || lower.ends_with(".glb") {
            let doc = gltf::Gltf::open(&path).ok()?;
            let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
            let buffers = doc.buffers().filter_map(|b| match b.source() {
                gltf::buffer::Source::Uri(uri) => Some(uri.to_string()),
                gltf::buffer::Source::Bin => None,
            });
            let images = doc.images().filter_map(|i| match i.source() {
                gltf::image::Source::Uri { uri, .. } => Some(uri.to_string()),
                gltf::image::Source::View { .. } => None,
            });
            files.push(path.clone());
            for uri in buffers.chain(images).filter(|u| !u.starts_with("data:")) {
                files.push(base.join(uri));
            }
        } else {
            files.push(path);
        }
    }
    Some(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `scenes/cornell_mesh` (a glTF with an external buffer) copied to a fresh directory.
    fn cornell_mesh_copy(tag: &str) -> (Scene, PathBuf) {
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell_mesh");
        let dir = std::env::temp_dir().join(format!("lf-memo-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        for f in ["scene.json", "short_box.gltf", "short_box.bin"] {
            std::fs::copy(src.join(f), dir.join(f)).unwrap();
        }
        let scene =
            Scene::from_json(&std::fs::read_to_string(dir.join("scene.json")).unwrap()).unwrap();
        (scene, dir)
    }

    const PLAIN: MemoOptions = MemoOptions {
        full: false,
        transport: None,
        codec: None,
    };

    /// The key is the same for the same inputs and changes with the settings, the options,
    /// the glTF file and the buffer it names; there is none when a file is missing.
    #[test]
    fn the_key_follows_every_input_a_bake_reads() {
        let (scene, dir) = cornell_mesh_copy("key");
        let files = mesh_files(&scene, &dir).unwrap();
        assert_eq!(
            files,
            vec![dir.join("short_box.gltf"), dir.join("short_box.bin")]
        );
        let key = |scene: &Scene, options: &MemoOptions| BundleMemo::key(scene, &dir, options);
        let base = key(&scene, &PLAIN).unwrap();
        assert_eq!(key(&scene, &PLAIN), Some(base.clone()));
        let mut more_rays = scene.clone();
        more_rays.settings.rays_per_texel += 1;
        assert_ne!(key(&more_rays, &PLAIN).unwrap(), base);
        for options in [
            MemoOptions {
                full: true,
                ..PLAIN
            },
            MemoOptions {
                transport: Some(Transport::Traced),
                ..PLAIN
            },
            MemoOptions {
                codec: Some(BundleCodec::F16),
                ..PLAIN
            },
        ] {
            assert_ne!(key(&scene, &options).unwrap(), base, "{options:?}");
        }
        for file in ["short_box.bin", "short_box.gltf"] {
            let path = dir.join(file);
            let bytes = std::fs::read(&path).unwrap();
            let mut changed = bytes.clone();
            if file.ends_with(".bin") {
                let last = changed.len() - 1;
                changed[last] ^= 1;
            } else {
                // Still valid JSON.
                changed.push(b' ');
            }
            std::fs::write(&path, &changed).unwrap();
            assert_ne!(key(&scene, &PLAIN).unwrap(), base, "{file} changed");
            std::fs::remove_file(&path).unwrap();
            assert_eq!(key(&scene, &PLAIN), None, "{file} missing");
            std::fs::write(&path, &bytes).unwrap();
            assert_eq!(key(&scene, &PLAIN), Some(base.clone()));
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
