//! The embedded [`BakeExecutor`]: loads a job's canonical scene and its assets from the store,
//! lays the assets out as files in a scratch directory (refusing a glTF asset that refers to a
//! file, which the loader would read from beside it), runs [`crate::bake::bake()`] with
//! the shared shape-operator cache, and encodes the bundle with the scene's codec settings.
//!
//! While the bake runs, each partial bundle the engine reports is encoded with the same options
//! and its bytes up to the table of contents are published: they are the final bundle's first
//! bytes (the engine's `sections_ready` invariant and deterministic encoding), so a client can
//! start on MRT before DRT and DNRT arrive.
//!
//! Both encodings read the level's encoding memo in the operator cache
//! ([`crate::bake::cache::encodings`], as `lightfarm bake --cache` does), and the final one keeps
//! its own there: a rebake after a clutter edit neither re-encodes nor recompresses the
//! unchanged transport and shapes, in the partial bundles or the final one. Between writes the
//! memo's session waits on disk (`hold_on_disk`), and the published prefix is held at its own
//! length, so the stages after the MRT part do not carry the partial write in memory.
//!
//! Invariants: runs on a runner thread inside the worker pool (never on the async runtime); the
//! bundle bytes are exactly those `lightfarm bake` writes for the same scene and settings; the
//! scratch directory is removed whatever the outcome (also when the bake unwinds on cancel).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use lightfarm_proto::bundle::{Bundle, EncodeOptions};
use lightfarm_proto::container::sections_end;
use lightfarm_proto::scene::Scene;

use super::job_progress::JobProgress;
use super::jobs::{BakeExecutor, BakeOutput};
use super::operator_cache;
use super::scene_inputs::{apply_overrides, asset_hash, AssetFormat};
use super::store::{BlobKind, BlobStore};
use crate::bake::cache::encodings::EncodingCache;
use crate::bake::cache::shape::ShapeCache;
use crate::bake::pipeline::encoding::{encode_and_keep, encode_options, encode_through};
use crate::bake::progress::Progress;
use crate::bake::scene::mesh::refuse_external_files;
use crate::bake::{bake, BakeOptions};

/// Bakes in this process.
pub struct PipelineExecutor {
    store: Arc<dyn BlobStore>,
    operator_cache: PathBuf,
    /// The operator cache is trimmed to this many bytes after every bake.
    operator_cache_bytes: u64,
    scratch: PathBuf,
    counter: AtomicU64,
}

impl PipelineExecutor {
    pub fn new(
        store: Arc<dyn BlobStore>,
        operator_cache: &Path,
        operator_cache_bytes: u64,
        scratch: &Path,
    ) -> Self {
        let _ = std::fs::remove_dir_all(scratch);
        PipelineExecutor {
            store,
            operator_cache: operator_cache.to_path_buf(),
            operator_cache_bytes,
            scratch: scratch.to_path_buf(),
            counter: AtomicU64::new(0),
        }
    }
}

/// The job's progress hook, plus encoding each partial bundle the engine reports with the
/// bundle's own options and publishing its bytes up to the table of contents.
struct StreamingProgress<'a> {
    job: &'a JobProgress,
    options: EncodeOptions,
    /// The level's encoding memo, which the final bundle's encoding then reads too.
    memo: Option<&'a EncodingCache>,
}

impl Progress for StreamingProgress<'_> {
    fn stage(&self, name: &str, total: u64) {
        self.job.stage(name, total);
    }

    fn advance(&self, n: u64) {
        self.job.advance(n);
    }

    fn wants_sections(&self) -> bool {
        true
    }

    fn sections_ready(&self, bundle: &Bundle) {
        let (bytes, report) = encode_through(bundle, &self.options, self.memo);
        let Some(end) = sections_end(&bytes) else {
            return;
        };
        let mut bytes = bytes;
        bytes.truncate(end);
        // Held until the job ends: not the whole write's capacity (twice the prefix at 1,000
        // blocks).
        bytes.shrink_to_fit();
        let names = report.sections.iter().map(|(n, _)| n.to_string()).collect();
        self.job.publish_prefix(bytes, names);
        // The rest of the bake runs without this write's encodings; the next write reads them
        // back.
        if let Some(memo) = self.memo {
            memo.hold_on_disk();
        }
    }
}

/// Removes a directory when dropped (also during an unwind).
pub struct ScratchDir(pub PathBuf);

impl Drop for ScratchDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

impl BakeExecutor for PipelineExecutor {
    fn run(
        &self,
        scene_id: &str,
        settings: &serde_json::Value,
        progress: &JobProgress,
    ) -> Result<BakeOutput, String> {
        let dir = self.scratch.join(format!(
            "{}-{}",
            &scene_id[..16],
            self.counter.fetch_add(1, Ordering::Relaxed)
        ));
        let (scene, dir) = prepare_scene(self.store.as_ref(), scene_id, settings, &dir)?;

        let cache = ShapeCache::open(&self.operator_cache)
            .map_err(|e| format!("operator cache {}: {e}", self.operator_cache.display()))?;
        let options = BakeOptions {
            cache: Some(cache),
            ..BakeOptions::default()
        };
        let memo = open_memo(&self.operator_cache, &scene);
        let streaming = StreamingProgress {
            job: progress,
            options: encode_options(&scene.settings, None),
            memo: memo.as_ref(),
        };
        let (bundle, report) =
            bake(&scene, &dir.0, &options, &streaming).map_err(|e| e.to_string())?;
        let trimmed = operator_cache::trim(&self.operator_cache, self.operator_cache_bytes);
        if trimmed.removed_files > 0 {
            tracing::info!(
                files = trimmed.removed_files,
                bytes = trimmed.removed_bytes,
                kept = trimmed.bytes,
                "operator cache trimmed to its budget (least recently used first)"
            );
        }
        if let Some(drt) = &report.drt {
            tracing::info!(
                scene = %scene_id,
                traced = drt.traced_texels,
                reused = drt.reused_texels,
                culled = drt.culled_texels,
                "drt rays: texels traced, reused from earlier bakes, and not traced (out of clutter's sight)"
            );
        }
        Ok(BakeOutput {
            bundle: encode_bundle(&scene, &bundle, memo.as_ref()),
            stage_seconds: report.stage_seconds,
            shape_keys: bundle.shapes.iter().map(|s| s.key.clone()).collect(),
            shapes_from_cache: report.shapes_from_cache as u64,
            shapes_computed: report.shapes_computed as u64,
        })
    }
}

/// Loads the canonical scene `scene_id` from the store, applies the settings overrides, and lays
/// its mesh assets out as files in `dir` (created; removed when the returned guard drops), under
/// the names the canonical scene gives them. Shared by the embedded executor and the farm's
/// workers, so both bake the same scene from the same files.
pub fn prepare_scene(
    store: &dyn BlobStore,
    scene_id: &str,
    settings: &serde_json::Value,
    dir: &Path,
) -> Result<(Scene, ScratchDir), String> {
    let bytes = store
        .get(BlobKind::Scene, scene_id)
        .map_err(|e| e.to_string())?
        .ok_or_else(|| format!("scene {scene_id} is no longer in the store; upload it again"))?;
    let text = std::str::from_utf8(&bytes).map_err(|e| format!("scene {scene_id}: {e}"))?;
    let scene = Scene::from_json(text).map_err(|e| e.to_string())?;
    let scene = apply_overrides(&scene, settings)?;

    let dir = ScratchDir(dir.to_path_buf());
    std::fs::create_dir_all(&dir.0).map_err(|e| format!("scratch directory: {e}"))?;
    let mut meshes: Vec<&String> = scene
        .clutter
        .iter()
        .filter_map(|c| c.mesh.as_ref())
        .collect();
    meshes.extend(scene.dynamic.iter().map(|d| &d.mesh));
    for file in meshes {
        let hash = asset_hash(file).ok_or_else(|| format!("mesh {file:?} is not an asset"))?;
        let asset = store
            .get(BlobKind::Asset, hash)
            .map_err(|e| e.to_string())?
            .ok_or_else(|| format!("asset {hash} is no longer in the store; upload it again"))?;
        // The upload refuses a glTF that refers to files, but an asset stored before that check
        // could still name one, which the bake would read from beside the scratch file.
        if let Some(format) = AssetFormat::detect(&asset) {
            refuse_external_files(&asset, format.mesh_format())
                .map_err(|e| format!("asset {hash}: {e}"))?;
        }
        std::fs::write(dir.0.join(file), asset.as_slice())
            .map_err(|e| format!("scratch directory: {e}"))?;
    }
    Ok((scene, dir))
}

/// The bundle's bytes as the service stores them: encoded with the scene's codec settings,
/// exactly as `lightfarm bake` writes them. Through the level's encoding memo when given
/// ([`open_memo`]), which then keeps this write's encodings for the next bake.
pub fn encode_bundle(scene: &Scene, bundle: &Bundle, memo: Option<&EncodingCache>) -> Vec<u8> {
    encode_and_keep(bundle, &encode_options(&scene.settings, None), memo).0
}

/// The level's encoding memo in the operator cache `dir`; None (encode without one) when it
/// cannot be opened or the build cannot be told.
pub fn open_memo(dir: &Path, scene: &Scene) -> Option<EncodingCache> {
    EncodingCache::open(dir, &scene.name)
        .map_err(|e| tracing::warn!(error = %e, "encoding memo unavailable"))
        .ok()
        .flatten()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::store::{content_hash, DiskStore};

    /// A one-triangle glTF whose buffer is `uri`.
    fn triangle_gltf(uri: &str) -> Vec<u8> {
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}],
"bufferViews":[{{"buffer":0,"byteLength":36}}],"buffers":[{{"byteLength":36,"uri":"{uri}"}}]}}"#
        )
        .into_bytes()
    }

    /// A stored glTF asset that names a file (as an upload before the upload check could) is
    /// refused when a bake lays its assets out, naming the asset and the URI; the same mesh with
    /// its buffer embedded is laid out as its file.
    #[test]
    fn a_stored_asset_that_names_a_file_is_refused_before_the_bake_reads_it() {
        let root =
            std::env::temp_dir().join(format!("lightfarm-executor-assets-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let store = DiskStore::open(&root.join("store"), 1 << 30).unwrap();
        let embedded = {
            use base64::engine::{general_purpose::STANDARD, Engine};
            let floats = [0f32, 0., 0., 1., 0., 0., 0., 1., 0.];
            let bytes: Vec<u8> = floats.iter().flat_map(|f| f.to_le_bytes()).collect();
            format!(
                "data:application/octet-stream;base64,{}",
                STANDARD.encode(bytes)
            )
        };
        for (uri, refused) in [("../../Cargo.toml", true), (embedded.as_str(), false)] {
            let asset = triangle_gltf(uri);
            let hash = store.put(BlobKind::Asset, &asset).unwrap();
            assert_eq!(hash, content_hash(&asset));
            let scene = format!(
                r#"{{"format":"lightfarm.scene/1","name":"s","blocks":[{{"id":"b","min":[0,0,0],"max":[2,2,2],"open":[],"albedo":[0.5,0.5,0.5]}}],
"clutter":[{{"id":"c","mesh":"{hash}.gltf","albedo":[0.5,0.5,0.5]}}]}}"#
            );
            let scene_id = store.put(BlobKind::Scene, scene.as_bytes()).unwrap();
            let dir = root.join("scratch");
            let result = prepare_scene(&store, &scene_id, &serde_json::json!({}), &dir);
            match result {
                Err(message) => {
                    assert!(refused, "{message}");
                    assert!(
                        message.contains(&format!("asset {hash}"))
                            && message.contains("\"../../Cargo.toml\""),
                        "{message}"
                    );
                    assert!(!dir.join(format!("{hash}.gltf")).exists());
                }
                Ok((_, scratch)) => {
                    assert!(!refused, "the asset naming a file was laid out");
                    let written = std::fs::read(scratch.0.join(format!("{hash}.gltf"))).unwrap();
                    assert_eq!(written, asset);
                }
            }
        }
        let _ = std::fs::remove_dir_all(&root);
    }
}
