//! The bake: scene → geometry → shape operators (cached) → inter-block transport → clutter
//! operators → probe volume → DNRT grids → SH responses → optional dense operator →
//! [`Bundle`].
//!
//! # Layout (in data-flow order)
//! - [`plan`]: which canonical shape each block applies ([`plan::ShapePlan`]).
//! - [`stages`]: each stage of the bake, cached where its inputs allow.
//! - [`to_bundle`]: the stages' results as the bundle's sections.
//! - [`encoding`]: the codecs the bundle is stored with, and one write of it through the
//!   level's encoding memo.
//!
//! [`bake`] here strings the stages together, times them ([`BakeReport::stage_seconds`]) and
//! announces each section as it becomes final ([`Progress::sections_ready`]) while a later stage
//! still runs ([`stages::stage_follows`]; after the last one the whole bundle is written).
//!
//! Invariant: the bundle is a pure function of the scene (and its meshes); the cache only saves
//! time. Operators are stored albedo-free; albedo enters through the layout.

use std::path::Path;
use std::time::Instant;

use lightfarm_proto::bundle::Bundle;
use lightfarm_proto::scene::{Scene, SceneError, Transport};

use crate::bake::cache::factors::FactorCache;
use crate::bake::cache::shape::ShapeCache;
use crate::bake::drt::build::{l_imp_rows, DrtInputs, DrtStats};
use crate::bake::drt::compaction::DeltaCompactionStats;
use crate::bake::drt::inpaint::inpainting_targets;
use crate::bake::memory::release_freed;
use crate::bake::mrt::shape::{ShapeError, ShapeOperators};
use crate::bake::progress::Progress;
use crate::bake::scene::geometry::{Geometry, GeometryError};
use crate::bake::scene::pieces::baked_scene;
use crate::bake::sh::responses::ShResponseStats;
use crate::bake::transport::build::TransportStats;
use stages::{stage_follows, LateStage};

pub mod encoding;
pub mod plan;
pub mod stages;
pub mod to_bundle;

/// What to bake beyond the scene's own settings.
#[derive(Clone, Debug, Default)]
pub struct BakeOptions {
    /// Shape-operator cache (None: compute everything).
    pub cache: Option<ShapeCache>,
    /// Also bake the dense one-bounce operator over all texels (`--method full`).
    pub full: bool,
    /// Override `settings.transport`.
    pub transport: Option<Transport>,
}

/// Figures about a bake.
#[derive(Clone, Debug, Default)]
pub struct BakeReport {
    pub blocks: usize,
    pub texels: usize,
    pub unique_shapes: usize,
    pub shapes_from_cache: usize,
    pub shapes_computed: usize,
    pub corrupt_cache_entries: usize,
    pub ranks: Vec<usize>,
    pub transport: TransportStats,
    /// The kind of inter-block transport the bake used (the scene's setting or the override);
    /// None only before the transport stage has run.
    pub transport_kind: Option<Transport>,
    /// The inter-block transport came from the cache (nothing about the blocks changed).
    pub transport_from_cache: bool,
    pub stage_seconds: Vec<(String, f64)>,
    pub bundle_bytes: usize,
    pub drt: Option<DrtStats>,
    /// What the low-rank form of the DRT operators saved (None without DRT or with
    /// `compact_deltas: false`).
    pub delta_compaction: Option<DeltaCompactionStats>,
    pub probes: usize,
    /// What the low-rank form of the probe volume's entries saved (None without a probe volume
    /// or with `compact_deltas: false`).
    pub probe_compaction: Option<DeltaCompactionStats>,
    /// Per dynamic object: (id, seconds to bake its DNRT grid or read it from the cache, grid
    /// data bytes).
    pub dnrt: Vec<(String, f64, usize)>,
    /// SH responses (`settings.sh_responses`), when baked.
    pub sh: Option<ShResponseStats>,
}

/// Why a bake failed.
#[derive(Debug, thiserror::Error)]
pub enum BakeError {
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error(transparent)]
    Geometry(#[from] GeometryError),
    #[error(transparent)]
    Shape(#[from] ShapeError),
    #[error("clutter operators: {0}")]
    Drt(String),
    #[error("transport compaction: {0}")]
    Transport(String),
    #[error("operator cache: {0}")]
    Cache(#[from] std::io::Error),
    /// A cached transport's operators could not be read back; its entry is dropped and
    /// [`bake`] bakes once more, computing the transport.
    #[error("operator cache: {0}")]
    CachedTransport(String),
}

impl From<crate::bake::math::low_rank::LowRankError> for BakeError {
    fn from(e: crate::bake::math::low_rank::LowRankError) -> BakeError {
        BakeError::Transport(e.to_string())
    }
}

/// Bakes a validated scene. `scene_dir` resolves mesh paths. When a cached transport's
/// operators turn out unreadable mid-bake (evicted or corrupt; the entry is dropped), it
/// bakes once more, computing the transport: the same bytes.
pub fn bake(
    scene: &Scene,
    scene_dir: &Path,
    options: &BakeOptions,
    progress: &dyn Progress,
) -> Result<(Bundle, BakeReport), BakeError> {
    let baked = match bake_once(scene, scene_dir, options, progress) {
        Err(BakeError::CachedTransport(why)) => {
            tracing::warn!(%why, "cached transport unreadable; baking again without it");
            bake_once(scene, scene_dir, options, progress)
        }
        done => done,
    };
    // The stages' operators are gone; what the caller does next (encode the bundle) grows
    // into pages the operating system can count as free.
    release_freed();
    baked
}

fn bake_once(
    scene: &Scene,
    scene_dir: &Path,
    options: &BakeOptions,
    progress: &dyn Progress,
) -> Result<(Bundle, BakeReport), BakeError> {
    scene.validate()?;
    // Long blocks are baked as pieces (`scene::pieces`); every stage sees the pieces.
    let cut = baked_scene(scene);
    let scene: &Scene = &cut;
    // An overridden transport is the scene's from here on: the shapes' specs depend on it
    // (`ShapeSpec::lightfield_rows`).
    let overridden;
    let scene = match options.transport {
        Some(t) if t != scene.settings.transport => {
            let mut s = scene.clone();
            s.settings.transport = t;
            overridden = s;
            &overridden
        }
        _ => scene,
    };
    let mut report = BakeReport::default();
    let mut timer = Instant::now();
    let mut lap = |report: &mut BakeReport, name: &str| {
        report
            .stage_seconds
            .push((name.to_string(), timer.elapsed().as_secs_f64()));
        timer = Instant::now();
    };
    // The bundle grows in file order; each step's sections are final once announced.
    let announce = |bundle: &Bundle| {
        if progress.wants_sections() {
            progress.sections_ready(bundle);
        }
    };
    let cache = options.cache.as_ref();
    let full_geometry = Geometry::from_scene(scene, scene_dir)?;
    let block_geometry = Geometry::blocks_only(scene);
    let openings = scene.openings()?;
    report.blocks = scene.blocks.len();
    report.texels = full_geometry.texels.len();
    lap(&mut report, "geometry");

    let plan = plan::shape_plan(scene);
    let stages::SplitShapes {
        operators: shapes,
        lightfields,
    } = stages::shape_operators(&plan, cache, progress, &mut report)?;
    lap(&mut report, "shape operators");

    let transport_kind = scene.settings.transport;
    let stages::BlockTransport {
        mut held,
        compact,
        stats,
        block_operators,
    } = stages::block_transport(
        scene,
        &plan,
        &block_geometry,
        &shapes,
        lightfields,
        &openings,
        transport_kind,
        cache,
        progress,
        &mut report,
    )?;
    report.transport = stats;
    report.transport_kind = Some(transport_kind);
    let mut block_operators = block_operators.unwrap_or_else(|| plan.block_operators(&shapes));
    // DRT reads a block's L_imp a row per hit: row-major, one copy per distinct operator.
    let l_imp_rows = if LateStage::ClutterOperators.runs(scene, options.full) {
        let refs: Vec<&ShapeOperators> = block_operators.iter().map(|s| s.as_ref()).collect();
        l_imp_rows(&refs)
    } else {
        Vec::new()
    };
    let inpainted = inpainting_targets(scene, &openings, &full_geometry);
    stages::strip_instances(scene, options.full, &inpainted, &mut block_operators);
    let per_block: Vec<&ShapeOperators> = block_operators.iter().map(|s| s.as_ref()).collect();
    // Only the bundle reads the compaction (the transport dropped the lightfields itself).
    let transport = to_bundle::transport_ops(compact, &held);
    let mut bundle =
        to_bundle::mrt_bundle(scene, &openings, &plan, &shapes, &full_geometry, transport);
    announce(&bundle);
    lap(&mut report, "transport");

    // A transport shipped uncompacted was held whole for the bundle; from here on only DRT's
    // inpainting reads it, and only into blocks where a texel may be buried (none without
    // clutter). Otherwise it is on disk, read block by block.
    if let stages::HeldTransport::Computed(mrt) = &mut held {
        mrt.retain_targets(&inpainted);
    }
    release_freed();
    let drt_inputs = DrtInputs {
        scene,
        openings: &openings,
        geometry: &full_geometry,
        block_geometry: &block_geometry,
        shapes: &per_block,
        l_imp_rows: &l_imp_rows,
        mrt: held.source(),
    };
    let mut drt = stages::clutter_operators(&drt_inputs, cache, progress)?;
    if let Some(ops) = &mut drt {
        report.drt = Some(ops.stats.clone());
        let factors = match cache {
            Some(c) => Some(FactorCache::open(c.dir())?),
            None => None,
        };
        let (section, stats) =
            to_bundle::drt_section(&bundle, ops, &scene.settings, factors.as_ref())?;
        report.delta_compaction = stats;
        bundle.drt = Some(section);
        if stage_follows(scene, options.full, LateStage::ClutterOperators) {
            announce(&bundle);
        }
    }
    drop(held);
    release_freed();
    lap(&mut report, "clutter operators");

    if let Some(volume) = stages::probe_volume(scene, &full_geometry, &per_block, drt.as_ref()) {
        report.probes = volume.n_probes;
        let (section, compaction) = to_bundle::probe_section(volume, &scene.settings)?;
        report.probe_compaction = compaction;
        bundle.probes = Some(section);
        if stage_follows(scene, options.full, LateStage::ProbeVolume) {
            announce(&bundle);
        }
    }
    lap(&mut report, "probe volume");

    if let Some((grids, shapes)) = stages::dnrt_grids(scene, scene_dir, cache, &mut report)? {
        bundle.dnrt = Some(grids);
        bundle.dynamic_shapes = shapes;
    }
    if bundle.dnrt.is_some() && stage_follows(scene, options.full, LateStage::DnrtGrids) {
        announce(&bundle);
    }
    lap(&mut report, "dnrt grids");

    if let Some(ops) =
        stages::sh_responses(scene, &full_geometry, &per_block, drt.as_ref(), progress)?
    {
        report.sh = Some(ops.stats.clone());
        bundle.sh = Some(to_bundle::sh_section(&ops));
        if stage_follows(scene, options.full, LateStage::ShResponses) {
            announce(&bundle);
        }
        lap(&mut report, "sh responses");
    }

    if options.full {
        let rows = stages::dense_operator(scene, &full_geometry, progress);
        bundle.full = Some(to_bundle::sparse_rows(rows));
    }
    lap(&mut report, "dense operator");
    Ok((bundle, report))
}
