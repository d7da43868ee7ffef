//! The bake's stages, in data-flow order: shape operators (cached by content) → inter-block
//! transport of the blocks alone (cached by the blocks and their shapes) → DRT clutter
//! operators → probe volume → DNRT grids (cached per object) → SH responses → the dense
//! operator. Each stage reads the earlier stages' results and returns its own; [`super::bake`]
//! strings them together and [`super::to_bundle`] turns them into sections.
//!
//! Invariant: a stage's result is a pure function of the scene (and meshes); a cache hit gives
//! what computing would, so the cache only saves time.

use faer::Mat;
use rayon::prelude::*;
use std::cell::Cell;
use std::path::Path;
use std::sync::Arc;

use lightfarm_proto::bundle::{DynamicShape, SourceBases};
use lightfarm_proto::dnrt_grid::DnrtGrid;
use lightfarm_proto::scene::{ProbeVolumeMode, Scene, Transform, Transport};

use crate::bake::cache::dnrt::{dnrt_key, DnrtCache, DnrtLookup};
use crate::bake::cache::entry::Lookup as EntryLookup;
use crate::bake::cache::shape::{Lookup, ShapeCache};
use crate::bake::cache::transport::{transport_key, LazyTransport, TransportCache};
use crate::bake::dnrt::grid::bake_dnrt_grid;
use crate::bake::drt::build::{build_drt, DrtInputs, DrtOperators};
use crate::bake::drt::error::DrtError;
use crate::bake::drt::rays::DrtRayCache;
use crate::bake::math::sampling::Purpose;
use crate::bake::mrt::one_bounce::gather_rows;
use crate::bake::mrt::shape::{bake_shape, ShapeLightfields, ShapeOperators, ShapeSpec};
use crate::bake::progress::Progress;
use crate::bake::scene::geometry::{Geometry, GeometryError};
use crate::bake::scene::mesh::{load_mesh, TriangleMesh};
use crate::bake::scene::mesh_albedo::SurfaceAlbedo;
use crate::bake::sh::probe_volume::{build_probe_volume, ProbeVolumeOps};
use crate::bake::sh::responses::{build_sh_responses, ShResponseOps};
use crate::bake::tracer::Tracer;
use crate::bake::transport::build::{
    lightfield_transport, BlockBox, MrtTransport, TracedTransport, TransportStats,
};
use crate::bake::transport::compaction::{compact_consuming, TargetPart};
use crate::bake::transport::flux::flux_first_transport;
use crate::bake::transport::source::TransportSource;
use crate::bake::transport::source_bases::factor_sources;

use super::plan::ShapePlan;
use super::{BakeError, BakeReport};

/// Every unique shape's operators (index = the plan's unique shape), from the cache or baked
/// and stored there; counts hits, corrupt entries and computed shapes in `report`. The
/// openings' lightfields come apart from the operators ([`SplitShapes`]) so that they can be
/// dropped once the transport is built; a cached shape's are not read here at all
/// ([`load_lightfields`] reads them when the transport is computed).
pub fn shape_operators(
    plan: &ShapePlan,
    cache: Option<&ShapeCache>,
    progress: &dyn Progress,
    report: &mut BakeReport,
) -> Result<SplitShapes, BakeError> {
    let ShapePlan {
        unique,
        unique_specs,
        ..
    } = plan;
    report.unique_shapes = unique.len();
    let mut to_compute: Vec<usize> = Vec::new();
    let mut slots: Vec<Option<ShapeOperators>> = vec![None; unique.len()];
    // Read and decoded one shape per core (a tenth of a second for the maze's ten shapes on
    // one), then taken in order.
    let lookups: Vec<Option<Lookup>> = unique
        .par_iter()
        .map(|key| cache.map(|c| c.get_operators(key)))
        .collect();
    for (i, lookup) in lookups.into_iter().enumerate() {
        match lookup {
            Some(Lookup::Hit(ops)) => {
                report.shapes_from_cache += 1;
                slots[i] = Some(*ops);
            }
            Some(Lookup::Corrupt) => {
                report.corrupt_cache_entries += 1;
                to_compute.push(i);
            }
            _ => to_compute.push(i),
        }
    }
    let texels_to_do: u64 = to_compute
        .iter()
        .map(|i| unique_specs[*i].n_texels() as u64)
        .sum();
    progress.stage("shape operators", texels_to_do);
    for i in to_compute {
        slots[i] = Some(bake_and_store(&unique_specs[i], cache, progress, report)?);
    }
    let shapes = SplitShapes::new(
        slots
            .into_iter()
            .map(|s| s.expect("every shape is cached or computed"))
            .collect(),
    );
    report.ranks = shapes.operators.iter().map(|s| s.rank()).collect();
    Ok(shapes)
}

/// The unique shapes as a bake holds them: the operators every stage reads, shared by the
/// blocks, and apart from them the openings' lightfields (`OutImp`, `W`), which only the
/// transport's propagation reads: two thirds of the bytes, dropped once the transport is built,
/// and not read from the cache unless it is built (`None`: in the cache, not read).
pub struct SplitShapes {
    pub operators: Vec<Arc<ShapeOperators>>,
    pub lightfields: Vec<Option<ShapeLightfields>>,
}

impl SplitShapes {
    /// Takes the lightfields out of `shapes` (as baked, or operators alone from the cache):
    /// `Some` for a shape whose every opening has its lightfield, `None` otherwise.
    pub fn new(shapes: Vec<ShapeOperators>) -> SplitShapes {
        let mut lightfields = Vec::with_capacity(shapes.len());
        let operators = shapes
            .into_iter()
            .map(|mut s| {
                let whole = s.openings.iter().all(|o| o.lightfield.is_some());
                let taken = s.take_lightfields();
                lightfields.push(whole.then_some(taken));
                Arc::new(s)
            })
            .collect();
        SplitShapes {
            operators,
            lightfields,
        }
    }
}

/// Every unique shape's lightfields for computing the transport: those the bake holds, the
/// others read from the cache, or — where their entry is gone (trimmed) or corrupt — the shape
/// baked again (its operators are the same bits: a bake is deterministic) and stored whole.
pub fn load_lightfields(
    plan: &ShapePlan,
    operators: &[Arc<ShapeOperators>],
    lightfields: Vec<Option<ShapeLightfields>>,
    cache: Option<&ShapeCache>,
    progress: &dyn Progress,
    report: &mut BakeReport,
) -> Result<Vec<ShapeLightfields>, BakeError> {
    let mut out: Vec<Option<ShapeLightfields>> = Vec::with_capacity(lightfields.len());
    for (i, held) in lightfields.into_iter().enumerate() {
        let found = match held {
            Some(held) => Some(held),
            None => match cache.map(|c| c.get_lightfields(&operators[i])) {
                Some(EntryLookup::Hit(read)) => Some(read),
                Some(EntryLookup::Corrupt) => {
                    report.corrupt_cache_entries += 1;
                    None
                }
                _ => None,
            },
        };
        out.push(found);
    }
    // The shapes whose lightfields are gone, baked again under one stage.
    let missing: Vec<usize> = (0..out.len()).filter(|&i| out[i].is_none()).collect();
    if !missing.is_empty() {
        let texels = missing
            .iter()
            .map(|&i| plan.unique_specs[i].n_texels() as u64)
            .sum();
        progress.stage("shape operators", texels);
        for &i in &missing {
            let mut ops = bake_and_store(&plan.unique_specs[i], cache, progress, report)?;
            out[i] = Some(ops.take_lightfields());
        }
    }
    Ok(out
        .into_iter()
        .map(|l| l.expect("every missing shape was baked again"))
        .collect())
}

/// Bakes one shape (advancing `progress` by its texels), stores it whole in `cache` and counts
/// it in `report`.
fn bake_and_store(
    spec: &ShapeSpec,
    cache: Option<&ShapeCache>,
    progress: &dyn Progress,
    report: &mut BakeReport,
) -> Result<ShapeOperators, BakeError> {
    let ops = bake_shape(spec, &|n| progress.advance(n))?;
    if let Some(cache) = cache {
        cache.put(&ops)?;
    }
    report.shapes_computed += 1;
    Ok(ops)
}

/// The blocks' f64 transport as the bake holds it: in memory (a transport the bundle ships
/// uncompacted), or on disk until DRT's inpainting asks for the few blocks it reads — in the
/// cache (a hit, or just computed and stored there), or, for a bake without a cache, in a
/// scratch directory removed with it.
pub enum HeldTransport {
    Computed(MrtTransport),
    Cached(LazyTransport),
    Scratch {
        lazy: LazyTransport,
        _dir: tempfile::TempDir,
    },
}

impl HeldTransport {
    /// Where DRT's inpainting reads it.
    pub fn source(&self) -> &dyn TransportSource {
        match self {
            HeldTransport::Computed(mrt) => mrt,
            HeldTransport::Cached(lazy) | HeldTransport::Scratch { lazy, .. } => lazy,
        }
    }
}

/// What the transport stage hands on.
pub struct BlockTransport {
    pub held: HeldTransport,
    /// Present when the scene ships compact transport: as the bundle ships it (f32, with the
    /// sources' shared bases).
    pub compact: Option<SourceBases>,
    pub stats: TransportStats,
    /// Per block, the operators it applies, when computing the transport made them (after the
    /// propagation, so that they and the lightfields are never held at once); None on a cache
    /// hit.
    pub block_operators: Option<Vec<Arc<ShapeOperators>>>,
}

/// The blocks' inter-block transport: from the cache (keyed by the blocks and their shapes'
/// keys, so clutter and lights never invalidate it) or computed by [`mrt_transport`] and
/// stored there. Sets `report.transport_from_cache`. A hit reads the compaction only (the
/// bundle's transport); the f64 operators are read whole only for a bundle that ships them.
/// Computed, the f64 transport goes to the cache (without one, to a scratch directory) as the
/// compaction is made and is held in memory only when the bundle ships it uncompacted: the
/// bake's memory never holds a large level's f64 transport beside its DRT stage.
#[allow(clippy::too_many_arguments)]
pub fn block_transport(
    scene: &Scene,
    plan: &ShapePlan,
    block_geometry: &Geometry,
    unique: &[Arc<ShapeOperators>],
    lightfields: Vec<Option<ShapeLightfields>>,
    openings: &[[Option<lightfarm_proto::scene::Opening>; 6]],
    transport_kind: Transport,
    cache: Option<&ShapeCache>,
    progress: &dyn Progress,
    report: &mut BakeReport,
) -> Result<BlockTransport, BakeError> {
    let transport_cache = match cache {
        Some(c) => Some(TransportCache::open(c.dir())?),
        None => None,
    };
    let block_shape_keys = plan.block_keys();
    let transport_key = transport_key(scene, transport_kind, &block_shape_keys);
    let cached = transport_cache.as_ref().and_then(|c| c.get(&transport_key));
    report.transport_from_cache = cached.is_some();
    if let Some(hit) = cached {
        let held = match hit.compact {
            Some(_) => HeldTransport::Cached(hit.transport),
            None => HeldTransport::Computed(
                hit.transport
                    .load_all()
                    .map_err(|e| BakeError::CachedTransport(e.to_string()))?,
            ),
        };
        return Ok(BlockTransport {
            held,
            compact: hit.compact,
            stats: hit.stats,
            block_operators: None,
        });
    }
    // Only the lightfield propagation reads the openings' lightfields.
    let lightfields = match transport_kind {
        Transport::Lightfield => {
            load_lightfields(plan, unique, lightfields, cache, progress, report)?
        }
        Transport::Traced => Vec::new(),
    };
    let (store, scratch) = match transport_cache {
        Some(c) => (c, None),
        None => {
            let dir = tempfile::Builder::new()
                .prefix("lightfarm-transport-")
                .tempdir()?;
            (TransportCache::open(dir.path())?, Some(dir))
        }
    };
    let computed = mrt_transport(
        scene,
        plan,
        block_geometry,
        unique,
        lightfields,
        openings,
        transport_kind,
        (&store, &transport_key),
        progress,
    )?;
    let held = match computed.whole {
        Some(mrt) => HeldTransport::Computed(mrt),
        None => match scratch {
            Some(dir) => HeldTransport::Scratch {
                lazy: computed.stored,
                _dir: dir,
            },
            None => HeldTransport::Cached(computed.stored),
        },
    };
    Ok(BlockTransport {
        held,
        compact: computed.compact,
        stats: computed.stats,
        block_operators: Some(computed.block_operators),
    })
}

/// The transport as [`mrt_transport`] computed it.
pub struct ComputedTransport {
    /// The whole f64 transport, in transport order, when the scene ships it uncompacted (the
    /// bundle is made of it); None when it ships the compaction (the f64 transport is then in
    /// the store alone).
    pub whole: Option<MrtTransport>,
    /// The transport as stored, read block by block.
    pub stored: LazyTransport,
    /// Present when the scene ships compact transport: as the bundle ships it (f32, with the
    /// sources' shared bases).
    pub compact: Option<SourceBases>,
    pub stats: TransportStats,
    /// Per block, the operators it applies ([`ShapePlan::block_operators`]).
    pub block_operators: Vec<Arc<ShapeOperators>>,
}

/// The MRT inter-block transport of the blocks alone (and its compaction when the scene ships
/// compact transport), stored in `store` (a transport cache and the key).
///
/// Memory, in order (what bounds a large level's bake): the lightfield propagation reads the
/// unique shapes' `lightfields` and each block's `Pass` operators alone; the lightfields are
/// dropped, then the per-block operators are made; the compaction then consumes the f64
/// transport target by target, storing each target's operators as it goes, so the whole f64
/// transport and its compaction are never held together.
#[allow(clippy::too_many_arguments)]
pub fn mrt_transport(
    scene: &Scene,
    plan: &ShapePlan,
    block_geometry: &Geometry,
    unique: &[Arc<ShapeOperators>],
    lightfields: Vec<ShapeLightfields>,
    openings: &[[Option<lightfarm_proto::scene::Opening>; 6]],
    transport_kind: Transport,
    store: (&TransportCache, &str),
    progress: &dyn Progress,
) -> Result<ComputedTransport, BakeError> {
    let settings = &scene.settings;
    // The lightfield transport is composed whole; the traced one is made target by target
    // below, as the compaction consumes it.
    let (lightfield, mut stats, block_operators) = match transport_kind {
        Transport::Lightfield => {
            progress.stage("lightfield transport", 1);
            let instances = plan.instance_passes(unique);
            let (blocks, stats) = lightfield_transport(
                &plan.block_passes(unique, &instances),
                &plan.block_lightfields(&lightfields),
                openings,
                settings.tolerance,
            );
            drop(instances);
            drop(lightfields);
            crate::bake::memory::release_freed();
            progress.advance(1);
            let block_operators = plan.block_operators(unique);
            (
                Some(MrtTransport::Lightfield(blocks)),
                stats,
                block_operators,
            )
        }
        Transport::Traced => {
            drop(lightfields);
            let block_operators = plan.block_operators(unique);
            (None, TransportStats::default(), block_operators)
        }
    };
    let per_block: Vec<&ShapeOperators> = block_operators.iter().map(|s| s.as_ref()).collect();
    let boxes: Vec<BlockBox> = match lightfield {
        Some(_) => Vec::new(),
        None => scene.blocks.iter().map(BlockBox::of).collect(),
    };
    let tracer = lightfield.is_none().then(|| {
        progress.stage("traced transport", block_geometry.texels.len() as u64);
        Tracer::new(block_geometry.primitives.clone(), block_geometry.scale())
    });
    let traced = tracer.as_ref().map(|tracer| {
        TracedTransport::new(
            block_geometry,
            tracer,
            &boxes,
            &per_block,
            settings.rays_per_texel,
            settings.seed,
            settings.tolerance,
        )
    });
    let (kept, dropped) = (Cell::new(0), Cell::new(0));
    let parts: Box<dyn Iterator<Item = TargetPart> + '_> = match (lightfield, &traced) {
        (Some(mrt), _) => {
            Box::new(
                mrt.split_by_target()
                    .into_iter()
                    .map(|(target, part)| TargetPart {
                        target,
                        transport: part,
                        noise: 0.0,
                    }),
            )
        }
        (None, Some(traced)) => Box::new((0..traced.blocks()).filter_map(|target| {
            let part = traced.into_target(target, &|n| progress.advance(n));
            kept.set(kept.get() + part.blocks.len());
            dropped.set(dropped.get() + part.dropped);
            (!part.blocks.is_empty()).then_some(TargetPart {
                target,
                transport: MrtTransport::Traced(part.blocks),
                noise: part.noise,
            })
        })),
        (None, None) => unreachable!("a traced transport without a tracer"),
    };
    let mut writer = store.0.writer(store.1, transport_kind == Transport::Traced);
    let (whole, compact) = if settings.compact_transport {
        let compact = compact_consuming(
            &per_block,
            parts,
            settings.tolerance,
            |c| super::to_bundle::compact_entry(&c),
            |target, part| -> Result<(), BakeError> { Ok(writer.target(target, &part)?) },
        )?;
        stats.compact_ranks = compact.iter().map(|c| c.y.cols as usize).collect();
        let rank: Vec<usize> = per_block.iter().map(|s| s.rank()).collect();
        let (mut factored, factoring) = factor_sources(compact, &rank, settings.tolerance)?;
        stats.factoring = factoring;
        let area: Vec<Vec<f64>> = block_geometry
            .block_texels
            .iter()
            .map(|texels| {
                texels
                    .clone()
                    .map(|x| block_geometry.texel_area(x))
                    .collect()
            })
            .collect();
        flux_first_transport(&mut factored, &area, &rank);
        (None, Some(factored))
    } else {
        // The bundle ships the transport itself: all of it stays.
        let mrt = MrtTransport::concat(transport_kind, parts.map(|part| part.transport));
        writer.all(&mrt)?;
        (Some(mrt), None)
    };
    stats.pairs_kept += kept.get();
    stats.pairs_dropped += dropped.get();
    let stored = writer.finish(compact.as_ref(), &stats)?;
    Ok(ComputedTransport {
        whole,
        stored,
        compact,
        stats,
        block_operators,
    })
}

/// DRT: the clutter operators (None for a scene without clutter), with the DRT ray passes
/// cached beside the shapes.
pub fn clutter_operators(
    inputs: &DrtInputs,
    cache: Option<&ShapeCache>,
    progress: &dyn Progress,
) -> Result<Option<DrtOperators>, BakeError> {
    if inputs.scene.clutter.is_empty() {
        return Ok(None);
    }
    let n = inputs.geometry.texels.len() as u64;
    progress.stage("clutter operators", n);
    let ray_cache = match cache {
        Some(c) => Some(DrtRayCache::open(c.dir())?),
        None => None,
    };
    let ops =
        build_drt(inputs, ray_cache.as_ref(), &|k| progress.advance(k)).map_err(|e| match e {
            DrtError::Transport(lost) => BakeError::CachedTransport(lost.to_string()),
            other => BakeError::Drt(other.to_string()),
        })?;
    Ok(Some(ops))
}

/// The clutter objects' DRT projections and the scene-clutter → DRT-clutter index map (empty
/// and all None without DRT).
fn clutter_of<'a>(
    scene: &Scene,
    drt: Option<&'a DrtOperators>,
) -> (
    &'a [crate::bake::drt::build::ClutterProjection],
    Vec<Option<usize>>,
) {
    match drt {
        Some(ops) => (&ops.clutter, ops.projection_of.clone()),
        None => (&[], vec![None; scene.clutter.len()]),
    }
}

/// After the transport stage, empties what no later stage reads from the blocks' own
/// operators (symmetry instances, which blocks of one shape and orientation share; an operator
/// held anywhere else, e.g. a shape the bundle ships, is left whole): the openings' `U_r` and
/// `U_b` unless DRT's inpainting reads one of its blocks (`inpainted`), and `L_imp` unless a
/// probe volume or SH responses follow (DRT reads its row-major copy). The openings stay
/// listed and the ranks unchanged (emptied matrices keep their columns), so what the transport
/// reaches and every size read later are the same. At 1,000 blocks the copies were ~0.4 GB of
/// the bake's peak.
pub fn strip_instances(
    scene: &Scene,
    full: bool,
    inpainted: &[bool],
    block_operators: &mut [Arc<ShapeOperators>],
) {
    let l_imp_read_later = [LateStage::ProbeVolume, LateStage::ShResponses]
        .into_iter()
        .any(|stage| stage.runs(scene, full));
    // The blocks sharing each operator, in first-use order.
    let mut groups: Vec<Vec<usize>> = Vec::new();
    let mut group_of = std::collections::HashMap::new();
    for (b, ops) in block_operators.iter().enumerate() {
        let g = *group_of.entry(Arc::as_ptr(ops)).or_insert_with(|| {
            groups.push(Vec::new());
            groups.len() - 1
        });
        groups[g].push(b);
    }
    let placeholder = Arc::new(ShapeOperators {
        key: String::new(),
        u_b: Mat::new(),
        t_db: Mat::new(),
        l_imp: Mat::new(),
        openings: Vec::new(),
        stats: Default::default(),
    });
    let empty = |m: &mut Mat<f64>| *m = Mat::zeros(0, m.ncols());
    for blocks in groups {
        if Arc::strong_count(&block_operators[blocks[0]]) != blocks.len() {
            continue; // held elsewhere too
        }
        // Every reference is the group's: take them all, then own the operators.
        let mut taken: Vec<_> = blocks
            .iter()
            .map(|&b| std::mem::replace(&mut block_operators[b], placeholder.clone()))
            .collect();
        let first = taken.swap_remove(0);
        drop(taken);
        let Ok(mut ops) = Arc::try_unwrap(first) else {
            unreachable!("the group held every reference");
        };
        if !blocks.iter().any(|&b| inpainted[b]) {
            empty(&mut ops.u_b);
            for o in &mut ops.openings {
                empty(&mut o.u_r);
            }
        }
        if !l_imp_read_later {
            empty(&mut ops.l_imp);
        }
        let ops = Arc::new(ops);
        for b in blocks {
            block_operators[b] = ops.clone();
        }
    }
}

/// The stages that may run after the transport, in bake order (see [`stage_follows`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum LateStage {
    ClutterOperators,
    ProbeVolume,
    DnrtGrids,
    ShResponses,
    DenseOperator,
}

impl LateStage {
    /// In bake order.
    const ALL: [LateStage; 5] = [
        LateStage::ClutterOperators,
        LateStage::ProbeVolume,
        LateStage::DnrtGrids,
        LateStage::ShResponses,
        LateStage::DenseOperator,
    ];

    /// Whether this stage runs for `scene` (`full`: the dense operator is asked for): the
    /// condition its function tests, kept here once for everything that asks which stages
    /// follow (a stage added to the bake is added here).
    pub fn runs(self, scene: &Scene, full: bool) -> bool {
        match self {
            LateStage::ClutterOperators => !scene.clutter.is_empty(),
            LateStage::ProbeVolume => probe_volume_wanted(scene),
            LateStage::DnrtGrids => !scene.dynamic.is_empty(),
            LateStage::ShResponses => scene.settings.sh_responses,
            LateStage::DenseOperator => full,
        }
    }
}

/// Whether a stage after `after` runs for `scene`. A partial bundle is announced only then:
/// otherwise the whole one is written next, and a partial write would run while the last
/// stage's operators are still held (the service's peak at 1,000 blocks).
pub fn stage_follows(scene: &Scene, full: bool, after: LateStage) -> bool {
    LateStage::ALL
        .into_iter()
        .any(|stage| stage > after && stage.runs(scene, full))
}

/// Whether [`probe_volume`] builds one for `scene`.
pub fn probe_volume_wanted(scene: &Scene) -> bool {
    match scene.settings.probe_volume {
        ProbeVolumeMode::Auto => !scene.dynamic.is_empty(),
        ProbeVolumeMode::Always => !(scene.clutter.is_empty() && scene.dynamic.is_empty()),
        ProbeVolumeMode::Never => false,
    }
}

/// `U_dyn`, the probe volume, when something will read it (`settings.probe_volume`: by default
/// when the scene has dynamic objects).
pub fn probe_volume(
    scene: &Scene,
    full_geometry: &Geometry,
    per_block: &[&ShapeOperators],
    drt: Option<&DrtOperators>,
) -> Option<ProbeVolumeOps> {
    if !probe_volume_wanted(scene) {
        return None;
    }
    let (clutter, projection_of) = clutter_of(scene, drt);
    Some(build_probe_volume(
        scene,
        full_geometry,
        per_block,
        clutter,
        &projection_of,
        &|_| {},
    ))
}

/// The DNRT grids and the dynamic objects' shapes (their triangles in their own frames, for
/// their direct shadows), one each per dynamic object in scene order (None without dynamic
/// objects). Each grid is content-cached (a grid depends on its object alone); `report.dnrt`
/// gets each object's seconds and grid bytes.
pub fn dnrt_grids(
    scene: &Scene,
    scene_dir: &Path,
    cache: Option<&ShapeCache>,
    report: &mut BakeReport,
) -> Result<Option<(Vec<DnrtGrid>, Vec<DynamicShape>)>, BakeError> {
    if scene.dynamic.is_empty() {
        return Ok(None);
    }
    let cache = match cache {
        Some(c) => Some(DnrtCache::open(c.dir())?),
        None => None,
    };
    let (mut grids, mut shapes) = (Vec::new(), Vec::new());
    for object in &scene.dynamic {
        let start = std::time::Instant::now();
        let mesh = dynamic_mesh(scene_dir, object)?;
        let grid = dnrt_grid_of(scene, object, &mesh, cache.as_ref())?;
        report.dnrt.push((
            object.id.clone(),
            start.elapsed().as_secs_f64(),
            grid.data_bytes(),
        ));
        grids.push(grid);
        shapes.push(DynamicShape {
            object: object.id.clone(),
            albedo: object.albedo.map(|a| a as f32),
            triangles: mesh
                .triangles
                .iter()
                .map(|t| t.map(|v| v.map(|x| x as f32)))
                .collect(),
        });
    }
    Ok(Some((grids, shapes)))
}

/// A dynamic object's mesh in its own frame.
fn dynamic_mesh(
    scene_dir: &Path,
    object: &lightfarm_proto::scene::DynamicObject,
) -> Result<TriangleMesh, BakeError> {
    Ok(load_mesh(
        &format!("dynamic \"{}\"", object.id),
        scene_dir,
        &object.mesh,
        &Transform::default(),
    )
    .map_err(GeometryError::from)?)
}

/// A dynamic object's DNRT grid: from the cache, or baked and stored there.
pub fn dnrt_grid(
    scene: &Scene,
    scene_dir: &Path,
    object: &lightfarm_proto::scene::DynamicObject,
    cache: Option<&DnrtCache>,
) -> Result<DnrtGrid, BakeError> {
    dnrt_grid_of(scene, object, &dynamic_mesh(scene_dir, object)?, cache)
}

/// [`dnrt_grid`] of the object's mesh, already loaded.
fn dnrt_grid_of(
    scene: &Scene,
    object: &lightfarm_proto::scene::DynamicObject,
    mesh: &TriangleMesh,
    cache: Option<&DnrtCache>,
) -> Result<DnrtGrid, BakeError> {
    let settings = &scene.settings;
    let key = dnrt_key(
        &mesh.triangles,
        object.albedo,
        &mesh.albedo,
        &settings.dnrt,
        settings.seed,
    );
    if let Some(DnrtLookup::Hit(grid)) = cache.map(|c| c.get(&key, &object.id)) {
        return Ok(*grid);
    }
    // The mesh's own colours where it has them, the object's albedo elsewhere.
    let albedo = if mesh.albedo.is_empty() {
        SurfaceAlbedo::Uniform(object.albedo)
    } else {
        SurfaceAlbedo::Mesh {
            albedo: &mesh.albedo,
            fallback: object.albedo,
        }
    };
    let grid = bake_dnrt_grid(
        &object.id,
        &mesh.triangles,
        albedo,
        &settings.dnrt,
        settings.seed,
    );
    if let Some(c) = cache {
        c.put(&key, &grid)?;
    }
    Ok(grid)
}

/// SH responses for normal-mapped surfaces (`settings.sh_responses`; None when not asked for).
pub fn sh_responses(
    scene: &Scene,
    full_geometry: &Geometry,
    per_block: &[&ShapeOperators],
    drt: Option<&DrtOperators>,
    progress: &dyn Progress,
) -> Result<Option<ShResponseOps>, BakeError> {
    if !scene.settings.sh_responses {
        return Ok(None);
    }
    progress.stage("sh responses", full_geometry.texels.len() as u64);
    let (clutter, projection_of) = clutter_of(scene, drt);
    let buried: &[u32] = drt.map_or(&[], |ops| &ops.buried);
    let ops = build_sh_responses(
        scene,
        full_geometry,
        per_block,
        clutter,
        &projection_of,
        buried,
        &|k| progress.advance(k),
    )
    .map_err(|e| BakeError::Drt(format!("sh responses: {e}")))?;
    Ok(Some(ops))
}

/// The dense Hašan-style one-bounce operator over the full geometry: per texel, its gather row
/// `(column, value)`.
pub fn dense_operator(
    scene: &Scene,
    full_geometry: &Geometry,
    progress: &dyn Progress,
) -> Vec<Vec<(u32, f32)>> {
    let settings = &scene.settings;
    progress.stage("dense operator", full_geometry.texels.len() as u64);
    let tracer = Tracer::new(full_geometry.primitives.clone(), full_geometry.scale());
    let all: Vec<usize> = (0..full_geometry.texels.len()).collect();
    gather_rows(
        full_geometry,
        &tracer,
        &all,
        settings.rays_per_texel,
        settings.seed,
        Purpose::FullOperator,
        &|n| progress.advance(n),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::mrt::shape::{OpeningOperators, ShapeStats};
    use lightfarm_proto::Face;

    fn mat(rows: usize, cols: usize) -> Mat<f64> {
        Mat::from_fn(rows, cols, |i, j| (i as f64 * 0.37 - j as f64 * 0.11).sin())
    }

    /// Rank 3, 10 texels, two openings of q = 2.
    fn operators() -> ShapeOperators {
        let opening = |face| OpeningOperators {
            face,
            u_r: mat(10, 2),
            pass_from: Vec::new(),
            lightfield: None,
        };
        ShapeOperators {
            key: "k".into(),
            u_b: mat(10, 3),
            t_db: Mat::new(),
            l_imp: mat(10, 3),
            openings: vec![opening(Face::ALL[0]), opening(Face::ALL[3])],
            stats: ShapeStats::default(),
        }
    }

    fn sizes(m: &Mat<f64>) -> (usize, usize) {
        (m.nrows(), m.ncols())
    }

    fn example(name: &str) -> Scene {
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../scenes/{name}/scene.json"));
        Scene::from_json(&std::fs::read_to_string(path).unwrap()).unwrap()
    }

    /// A partial bundle is announced after a stage only when a later one runs: each stage's
    /// own condition, in bake order.
    #[test]
    fn a_stage_follows_only_when_a_later_one_runs() {
        use LateStage::*;
        let mut cornell = example("cornell");
        assert!(!cornell.clutter.is_empty() && cornell.dynamic.is_empty());
        assert!(!stage_follows(&cornell, false, ClutterOperators));
        assert!(stage_follows(&cornell, true, ClutterOperators));
        assert!(stage_follows(&cornell, true, ShResponses));
        assert!(!stage_follows(&cornell, true, DenseOperator));
        cornell.settings.probe_volume = ProbeVolumeMode::Always;
        assert!(stage_follows(&cornell, false, ClutterOperators));
        assert!(!stage_follows(&cornell, false, ProbeVolume));
        cornell.settings.sh_responses = true;
        assert!(stage_follows(&cornell, false, ProbeVolume));
        assert!(stage_follows(&cornell, false, DnrtGrids));
        assert!(!stage_follows(&cornell, false, ShResponses));

        let mut balls = example("ball_corridor");
        assert!(!balls.dynamic.is_empty() && !balls.settings.sh_responses);
        assert!(stage_follows(&balls, false, ClutterOperators));
        assert!(stage_follows(&balls, false, ProbeVolume));
        assert!(!stage_follows(&balls, false, DnrtGrids));
        balls.settings.sh_responses = true;
        assert!(stage_follows(&balls, false, DnrtGrids));
        assert!(!stage_follows(&balls, false, ShResponses));
        balls.settings.probe_volume = ProbeVolumeMode::Never;
        balls.dynamic.clear();
        balls.settings.sh_responses = false;
        assert!(!stage_follows(&balls, false, ClutterOperators));
    }

    /// A block's own copies lose what no later stage reads, keeping ranks and openings; a
    /// shape shared with the bundle is never touched; `L_imp` stays when a probe volume or SH
    /// responses will read it.
    #[test]
    fn stripping_keeps_what_later_stages_read() {
        let mut scene = example("cornell");
        assert!(!probe_volume_wanted(&scene) && !scene.settings.sh_responses);
        for sh in [false, true] {
            scene.settings.sh_responses = sh;
            let shared = Arc::new(operators());
            let (one, two) = (Arc::new(operators()), Arc::new(operators()));
            let mut blocks = vec![shared.clone(), one.clone(), two.clone(), two];
            drop(one);
            // Block 1 is no inpainting target; blocks 2 and 3 share one instance, and 3 is.
            strip_instances(&scene, false, &[false, false, false, true], &mut blocks);
            assert!(Arc::ptr_eq(&blocks[2], &blocks[3]));
            assert!(Arc::ptr_eq(&blocks[0], &shared));
            assert_eq!(sizes(&blocks[0].u_b), (10, 3));
            assert_eq!(sizes(&blocks[0].l_imp), (10, 3));
            assert_eq!(sizes(&blocks[1].u_b), (0, 3));
            assert_eq!(sizes(&blocks[2].u_b), (10, 3));
            for (b, u_r) in [(0, (10, 2)), (1, (0, 2)), (2, (10, 2))] {
                assert_eq!(blocks[b].openings.len(), 2);
                for o in &blocks[b].openings {
                    assert_eq!(sizes(&o.u_r), u_r, "block {b}");
                }
                assert_eq!(blocks[b].rank(), 3);
            }
            let l_imp = if sh { (10, 3) } else { (0, 3) };
            assert_eq!(sizes(&blocks[1].l_imp), l_imp);
            assert_eq!(sizes(&blocks[2].l_imp), l_imp);
        }
    }
}
