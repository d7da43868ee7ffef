//! Scenes as the API receives them: parsing, mesh references to uploaded assets, settings
//! overrides, and the size of a bake (for the limits). Shared by the handlers (validation) and
//! the executor (the bake), so both see the same scene.
//!
//! Invariants:
//! - In an API scene a mesh path names an uploaded asset by its hash (`"<hash>"`, or
//!   `"<hash>.<ext>"`); the canonical scene stored under the scene id always has the
//!   `"<hash>.<ext>"` form, with the extension of the asset's detected format, so the bake can
//!   lay the assets out as files under those names.
//! - The canonical JSON is `serde_json` of the parsed [`Scene`]: equal scenes get equal ids.
//! - Settings overrides are merged field by field into the scene's settings and the result is
//!   validated like any scene; a bake's id hashes the scene id and the effective settings.

use lightfarm_proto::api::SceneCreated;
use lightfarm_proto::scene::{Scene, Settings};

use super::store::is_hash;
use crate::bake::scene::geometry::Geometry;
use crate::bake::scene::mesh::MeshFormat;

/// A mesh format the service accepts, detected from the bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AssetFormat {
    Glb,
    Gltf,
    Obj,
}

impl AssetFormat {
    pub fn extension(self) -> &'static str {
        match self {
            AssetFormat::Glb => "glb",
            AssetFormat::Gltf => "gltf",
            AssetFormat::Obj => "obj",
        }
    }

    /// The parser the bake uses for this format.
    pub fn mesh_format(self) -> MeshFormat {
        match self {
            AssetFormat::Glb | AssetFormat::Gltf => MeshFormat::Gltf,
            AssetFormat::Obj => MeshFormat::Obj,
        }
    }

    /// GLB by its magic, glTF JSON by its opening brace, OBJ as any other UTF-8 text.
    pub fn detect(bytes: &[u8]) -> Option<AssetFormat> {
        if bytes.starts_with(b"glTF") {
            return Some(AssetFormat::Glb);
        }
        let text = std::str::from_utf8(bytes).ok()?;
        match text.trim_start().chars().next() {
            Some('{') => Some(AssetFormat::Gltf),
            Some(_) => Some(AssetFormat::Obj),
            None => None,
        }
    }
}

/// Every mesh path of a scene with the object that names it.
pub fn mesh_references(scene: &Scene) -> Vec<(String, String)> {
    let mut refs = Vec::new();
    for c in &scene.clutter {
        if let Some(mesh) = &c.mesh {
            refs.push((format!("clutter \"{}\"", c.id), mesh.clone()));
        }
    }
    for d in &scene.dynamic {
        refs.push((format!("dynamic \"{}\"", d.id), d.mesh.clone()));
    }
    refs
}

/// The asset hash a mesh path names, if it names one.
pub fn asset_hash(path: &str) -> Option<&str> {
    let stem = path.split_once('.').map(|(s, _)| s).unwrap_or(path);
    is_hash(stem).then_some(stem)
}

/// Rewrites every mesh path of a scene document (`clutter[].mesh`, `dynamic[].mesh`) with
/// `resolve(object, hash)`, which returns the stored file name or an error message naming the
/// object. Works on the JSON before it is parsed, since a parsed [`Scene`] requires mesh paths
/// with a file extension.
pub fn rewrite_meshes(
    document: &mut serde_json::Value,
    mut resolve: impl FnMut(&str, &str) -> Result<String, String>,
) -> Result<(), String> {
    for (list, kind) in [("clutter", "clutter"), ("dynamic", "dynamic")] {
        let Some(objects) = document.get_mut(list).and_then(|v| v.as_array_mut()) else {
            continue;
        };
        for object in objects {
            let id = object
                .get("id")
                .and_then(|v| v.as_str())
                .unwrap_or("?")
                .to_string();
            let Some(mesh) = object.get_mut("mesh") else {
                continue;
            };
            let Some(path) = mesh.as_str() else {
                continue; // the parser names the type error
            };
            let name = format!("{kind} \"{id}\"");
            let hash = asset_hash(path).ok_or_else(|| {
                format!(
                    "{name}: mesh {path:?} does not name an uploaded asset (POST /v1/assets \
                     returns the hash to use)"
                )
            })?;
            *mesh = serde_json::Value::String(resolve(&name, hash)?);
        }
    }
    Ok(())
}

/// The canonical bytes of a scene (its id is their hash).
pub fn canonical_json(scene: &Scene) -> Vec<u8> {
    serde_json::to_vec(scene).expect("a scene always serialises")
}

/// The scene with `overrides` (a JSON object of settings fields) merged into its settings,
/// validated.
pub fn apply_overrides(scene: &Scene, overrides: &serde_json::Value) -> Result<Scene, String> {
    let mut scene = scene.clone();
    match overrides {
        serde_json::Value::Null => {}
        serde_json::Value::Object(fields) => {
            let mut settings =
                serde_json::to_value(&scene.settings).expect("settings always serialise");
            let target = settings.as_object_mut().expect("settings is an object");
            for (name, value) in fields {
                if !target.contains_key(name) {
                    return Err(format!("settings.{name}: not a setting"));
                }
                target.insert(name.clone(), value.clone());
            }
            scene.settings = serde_json::from_value::<Settings>(settings)
                .map_err(|e| format!("settings: {e}"))?;
        }
        other => return Err(format!("settings: expected an object, found {other}")),
    }
    scene.validate().map_err(|e| e.to_string())?;
    Ok(scene)
}

/// Texels a bake of `scene` holds in block faces and box clutter. Mesh clutter's texels are not
/// counted: they are known only once its meshes are loaded (a known gap, `ARCHITECTURE.md`).
pub fn texel_count(scene: &Scene) -> u64 {
    let t = scene.settings.texels_per_face as u64;
    let boxes = scene.clutter.iter().filter(|c| c.box_.is_some()).count() as u64;
    Geometry::blocks_only(scene).texels.len() as u64 + boxes * 6 * t * t
}

/// What `POST /v1/scenes` answers and `GET /v1/scenes` lists for the stored scene `id`.
pub fn scene_summary(id: String, scene: &Scene) -> SceneCreated {
    SceneCreated {
        id,
        name: scene.name.clone(),
        blocks: scene.blocks.len() as u64,
        clutter: scene.clutter.len() as u64,
        dynamic: scene.dynamic.len() as u64,
        texels: texel_count(scene),
    }
}

/// Stages the bake reports (for the overall progress fraction).
pub fn expected_stages(scene: &Scene) -> usize {
    2 + usize::from(!scene.clutter.is_empty())
}

/// The id of a bake of `scene_id` with the effective `settings`.
pub fn bake_id(scene_id: &str, settings: &Settings) -> String {
    let mut hasher = blake3::Hasher::new();
    hasher.update(b"lightfarm bake 1\0");
    hasher.update(scene_id.as_bytes());
    hasher.update(b"\0");
    hasher.update(&serde_json::to_vec(settings).expect("settings always serialise"));
    hasher.finalize().to_hex().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn detects_formats() {
        assert_eq!(
            AssetFormat::detect(b"glTF\x02\0\0\0"),
            Some(AssetFormat::Glb)
        );
        assert_eq!(
            AssetFormat::detect(b"  {\"asset\":{}}"),
            Some(AssetFormat::Gltf)
        );
        assert_eq!(AssetFormat::detect(b"v 0 0 0\n"), Some(AssetFormat::Obj));
        assert_eq!(AssetFormat::detect(b"\xff\xfe"), None);
        assert_eq!(AssetFormat::detect(b"   "), None);
    }

    #[test]
    fn asset_hash_accepts_hash_with_or_without_extension() {
        let h = "a".repeat(64);
        assert_eq!(asset_hash(&h), Some(h.as_str()));
        assert_eq!(asset_hash(&format!("{h}.glb")), Some(h.as_str()));
        assert_eq!(asset_hash("meshes/chair.obj"), None);
        assert_eq!(asset_hash(&"A".repeat(64)), None);
    }
}
