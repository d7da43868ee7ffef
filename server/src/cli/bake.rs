//! `lightfarm bake SCENE.json -o OUT.lfb`: bake a scene into an operator bundle.

use std::path::{Path, PathBuf};

use lightfarm_proto::scene::{BundleCodec, Scene, Transport};

use super::progress_bar::Bar;
use super::{read_text, write_atomic};
use crate::bake::cache::bundle_memo::{BundleMemo, MemoOptions};
use crate::bake::cache::encodings::EncodingCache;
use crate::bake::cache::shape::ShapeCache;
use crate::bake::pipeline::encoding::{encode_and_keep, encode_options};
use crate::bake::{bake, BakeOptions};

/// Arguments of `bake`.
pub struct BakeArgs {
    pub scene: PathBuf,
    pub out: PathBuf,
    pub cache: Option<PathBuf>,
    pub full: bool,
    pub transport: Option<Transport>,
    /// Override `settings.bundle_codec`.
    pub codec: Option<BundleCodec>,
    pub quiet: bool,
}

/// Longest list the bake log prints whole; longer ones (a game-sized level has a rank per
/// block) are summarised.
const LIST_WHOLE: usize = 24;

/// `[a, b, c]` for a short list, `N values: min a, median b, max c` for a long one.
fn list<T: Copy + Ord + std::fmt::Debug>(values: &[T]) -> String {
    if values.len() <= LIST_WHOLE {
        return format!("{values:?}");
    }
    let mut sorted = values.to_vec();
    sorted.sort_unstable();
    format!(
        "({} values: min {:?}, median {:?}, max {:?})",
        sorted.len(),
        sorted[0],
        sorted[sorted.len() / 2],
        sorted[sorted.len() - 1]
    )
}

/// Loads and validates a scene file; returns it with its directory.
pub fn load_scene(path: &Path) -> anyhow::Result<(Scene, PathBuf)> {
    let text = read_text(path)?;
    let scene = Scene::from_json(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    Ok((scene, dir))
}

pub fn run(args: BakeArgs) -> anyhow::Result<()> {
    let (scene, dir) = load_scene(&args.scene)?;
    let cache = match &args.cache {
        Some(dir) => Some(ShapeCache::open(dir)?),
        None => None,
    };
    // A rebake of inputs this build baked before: the bytes it wrote then.
    let memo = match &args.cache {
        Some(cache_dir) => {
            let options = MemoOptions {
                full: args.full,
                transport: args.transport,
                codec: args.codec,
            };
            let key = BundleMemo::key(&scene, &dir, &options);
            Some((BundleMemo::open(cache_dir)?, key))
        }
        None => None,
    };
    if let Some((memo, Some(key))) = &memo {
        let start = std::time::Instant::now();
        if let Some(bytes) = memo.get(key) {
            write_atomic(&args.out, &bytes)?;
            if !args.quiet {
                eprintln!(
                    "baked {}: the same inputs (scene, options, mesh files) were baked by this \
                     build before; their bundle is reused from the cache ({})",
                    scene.name,
                    memo.path(key).display()
                );
                crate::say!(
                    "bundle={} bytes={} bake_seconds={:.3}",
                    args.out.display(),
                    bytes.len(),
                    start.elapsed().as_secs_f64()
                );
            }
            return Ok(());
        }
    }
    let options = BakeOptions {
        cache,
        full: args.full,
        transport: args.transport,
    };
    let bar = Bar::new();
    let (bundle, mut report) = bake(&scene, &dir, &options, &bar)?;
    bar.finish();
    let started = std::time::Instant::now();
    // The level's last write's matrix encodings: a rebake writes most matrices unchanged.
    let encodings = match &args.cache {
        Some(dir) => EncodingCache::open(dir, &scene.name)?,
        None => None,
    };
    let (bytes, encoded) = encode_and_keep(
        &bundle,
        &encode_options(&scene.settings, args.codec),
        encodings.as_ref(),
    );
    drop(bundle);
    let encode_seconds = started.elapsed().as_secs_f64();
    let started = std::time::Instant::now();
    report.bundle_bytes = bytes.len();
    write_atomic(&args.out, &bytes)?;
    if let Some((memo, Some(key))) = &memo {
        if let Err(e) = memo.put(key, &bytes) {
            // Only a later rebake's time depends on it.
            tracing::warn!(error = %e, "could not memoise the bundle in the cache");
        }
    }
    let write_seconds = started.elapsed().as_secs_f64();
    if !args.quiet {
        eprintln!(
            "baked {}: {} blocks, {} texels, {} shapes ({} from cache, {} computed), ranks {}",
            scene.name,
            report.blocks,
            report.texels,
            report.unique_shapes,
            report.shapes_from_cache,
            report.shapes_computed,
            list(&report.ranks)
        );
        let t = &report.transport;
        if report.transport_kind == Some(Transport::Lightfield) {
            eprintln!(
                "transport (lightfield): {} propagation steps ({} cut, max {} hops); compact ranks {}",
                t.steps, t.cut, t.max_hops, list(&t.compact_ranks)
            );
        } else {
            eprintln!(
                "transport (traced): {} (source, target) pairs kept, {} dropped; compact ranks {}",
                t.pairs_kept,
                t.pairs_dropped,
                list(&t.compact_ranks)
            );
        }
        let f = &t.factoring;
        if f.sources > 0 {
            eprintln!(
                "transport sources: {} of {} with a shared basis, ranks {}; Z values {} -> {} (bases included)",
                f.basis_ranks.len(), f.sources, list(&f.basis_ranks), f.values_before, f.values_after
            );
        }
        if let Some(d) = &report.drt {
            eprintln!(
                "drt: {} scene texels with rows, {} skipped (view of clutter below tolerance), {} buried scene texels ({} without a valid neighbour), {} buried clutter texels, {} scene texels gathered exactly, clutter ranks {}",
                d.scene_texels_with_rows, d.scene_texels_skipped, d.buried_scene_texels, d.inpainted_without_neighbours, d.buried_clutter_texels, d.scene_texels_gathered, list(&d.clutter_ranks)
            );
            eprintln!(
                "drt rays: {} texels traced, {} reused from the cache (nothing they saw changed), {} not traced (out of clutter's sight through the openings)",
                d.traced_texels, d.reused_texels, d.culled_texels
            );
        }
        if let Some(s) = &report.sh {
            eprintln!(
                "sh responses: {} texels with rows ({} buried), {} entries, rank {} of {} source columns kept ({} values, {} unfactored), largest dropped energy {:.2e}",
                s.texels_with_rows, s.buried_texels, s.entries, s.kept_rank, s.full_width, s.stored_values, s.dense_values, s.max_dropped_energy
            );
        }
        if let Some(c) = &report.delta_compaction {
            eprintln!(
                "drt low rank: {} entries factored, {} dense, values {} -> {}; exact gather {} sparse entries -> {} factor values + {} sparse; ranks {}",
                c.factored, c.dense, c.values_before, c.values_after, c.gather_sparse_before, c.gather_factor_values, c.gather_sparse_left, list(&c.ranks)
            );
        }
        if let Some(c) = &report.probe_compaction {
            eprintln!(
                "probes low rank: {} entries factored, {} dense, values {} -> {}; ranks {}",
                c.factored,
                c.dense,
                c.values_before,
                c.values_after,
                list(&c.ranks)
            );
        }
        for (id, seconds, bytes) in &report.dnrt {
            eprintln!("dnrt: \"{id}\" grid {bytes} bytes in {seconds:.3}s (bake or cache lookup)");
        }
        let sizes: Vec<String> = encoded
            .sections
            .iter()
            .map(|(n, i)| format!("{n} {}/{}", i.stored_len, i.raw_len))
            .collect();
        eprintln!(
            "sections (stored/raw bytes): {}; probes: {}",
            sizes.join(", "),
            report.probes
        );
        let codecs: Vec<String> = encoded
            .codecs
            .iter()
            .map(|(n, u)| {
                let predicted = if u.predicted > 0 {
                    format!(" ({} predicted)", u.predicted)
                } else {
                    String::new()
                };
                format!("{n} {} matrices{predicted} {} values", u.matrices, u.values)
            })
            .collect();
        eprintln!(
            "codecs: {}; largest codec error {:.2e}",
            codecs.join(", "),
            encoded.max_codec_error
        );
        let stages: Vec<String> = report
            .stage_seconds
            .iter()
            .map(|(n, s)| format!("{n} {s:.3}s"))
            .collect();
        eprintln!(
            "stages: {}; then encode {encode_seconds:.3}s, write {write_seconds:.3}s",
            stages.join(", ")
        );
        let total: f64 = report.stage_seconds.iter().map(|(_, s)| s).sum();
        crate::say!(
            "bundle={} bytes={} bake_seconds={total:.3}",
            args.out.display(),
            report.bundle_bytes
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::list;

    #[test]
    fn long_lists_are_summarised() {
        assert_eq!(list(&[3, 1, 2]), "[3, 1, 2]");
        let long: Vec<u32> = (0..100).rev().collect();
        assert_eq!(list(&long), "(100 values: min 0, median 50, max 99)");
        assert_eq!(list(&vec![7u32; 24]), format!("{:?}", vec![7u32; 24]));
    }
}
