//! The bake: scene → geometry → shape operators (cached) → inter-block transport → optional
//! dense operator → [`Bundle`].
//!
//! Invariant: the bundle is a pure function of the scene (and its meshes); the cache only saves
//! time. Operators are stored albedo-free; albedo enters through the layout.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use lightfarm_proto::bundle::{self, Bundle, Layout, SparseRows, SurfaceInfo, TransportOps};
use lightfarm_proto::scene::{ProbeVolumeMode, Scene, SceneError, Settings, Transform, Transport};

use crate::bake::cache::dnrt::{dnrt_key, DnrtCache, DnrtLookup};
use crate::bake::cache::shape::{Lookup, ShapeCache};
use crate::bake::cache::transport::{transport_key, CachedTransport, TransportCache};
use crate::bake::dnrt::grid::bake_dnrt_grid;
use crate::bake::drt::build::{build_drt, DeltaBlock, DrtOperators, DrtStats};
use crate::bake::drt::compaction::{compact_entry_keeping, compact_gather, DeltaCompactionStats};
use crate::bake::drt::rays::DrtRayCache;
use crate::bake::math::low_rank::LowRankError;
use crate::bake::math::matrix::to_matrix;
use crate::bake::math::sampling::Purpose;
use crate::bake::mrt::one_bounce::gather_rows;
use crate::bake::mrt::shape::{bake_shape, ShapeError, ShapeOperators, ShapeSpec};
use crate::bake::mrt::shape_symmetry::instance_operators;
use crate::bake::progress::Progress;
use crate::bake::scene::geometry::{Geometry, GeometryError, Primitive, SurfaceOwner};
use crate::bake::scene::mesh::load_mesh;
use crate::bake::scene::mesh_albedo::SurfaceAlbedo;
use crate::bake::sh::probe_volume::build_probe_volume;
use crate::bake::sh::responses::{build_sh_responses, ShResponseStats};
use crate::bake::tracer::Tracer;
use crate::bake::transport::build::{
    lightfield_transport, traced_transport, MrtTransport, TransportStats,
};
use crate::bake::transport::compaction::compact_transport;
use lightfarm_proto::box_symmetry::BoxSymmetry;

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
    /// The inter-block transport came from the cache (nothing about the blocks changed).
    pub transport_from_cache: bool,
    pub stage_seconds: Vec<(String, f64)>,
    pub bundle_bytes: usize,
    pub drt: Option<DrtStats>,
    /// What the low-rank form of the DRT operators saved (None without DRT or with
    /// `compact_deltas: false`).
    pub delta_compaction: Option<DeltaCompactionStats>,
    pub probes: usize,
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
}

/// The bundle's DRT section from the DRT operators: delta entries and the exact gather in
/// low-rank form when `compact_deltas` (see [`crate::bake::drt::compaction`]).
fn drt_section(
    bundle: &Bundle,
    ops: &DrtOperators,
    settings: &Settings,
) -> Result<(bundle::DrtOps, Option<DeltaCompactionStats>), BakeError> {
    let clutter: Vec<bundle::ClutterOps> = ops
        .clutter
        .iter()
        .map(|c| bundle::ClutterOps {
            id: c.id.clone(),
            texel_offset: c.texel_offset as u32,
            t_dc: to_matrix(&c.basis.basis.transpose().to_owned()),
        })
        .collect();
    if !settings.compact_deltas {
        let drt = bundle::DrtOps {
            clutter,
            entries: ops.entries.iter().map(to_entry).collect(),
            buried: ops.buried.clone(),
            // In the form the bundle stores it (rows by column), so it decodes as it is here.
            direct_gather: ops.direct_gather.as_ref().map(|g| g.sorted()),
            replaced: ops.replaced.clone(),
        };
        return Ok((drt, None));
    }
    let low_rank = |e: LowRankError| BakeError::Drt(format!("delta compaction: {e}"));
    let mut stats = DeltaCompactionStats::default();
    let mut entries = Vec::with_capacity(ops.entries.len());
    let mut buried = ops.buried.clone();
    buried.sort_unstable();
    for e in &ops.entries {
        entries.extend(
            compact_entry_keeping(
                &e.rows,
                e.source,
                &e.matrix,
                &buried,
                settings.tolerance,
                &mut stats,
            )
            .map_err(low_rank)?,
        );
    }
    let mut direct_gather = None;
    if let Some(g) = &ops.direct_gather {
        // Source ranges: every block's texels and every clutter object's.
        let ranges: Vec<(u32, u32)> = bundle
            .blocks
            .iter()
            .map(|b| (b.texel_offset, bundle.shapes[b.shape as usize].u_b.rows))
            .chain(clutter.iter().map(|c| (c.texel_offset, c.t_dc.cols)))
            .collect();
        let (gathered, rest) =
            compact_gather(g, &ranges, settings.tolerance, &mut stats).map_err(low_rank)?;
        entries.extend(gathered);
        direct_gather = rest.map(|g| g.sorted());
    }
    let drt = bundle::DrtOps {
        clutter,
        entries,
        buried: ops.buried.clone(),
        direct_gather,
        replaced: ops.replaced.clone(),
    };
    Ok((drt, Some(stats)))
}

fn to_entry(e: &DeltaBlock) -> bundle::DeltaEntry {
    bundle::DeltaEntry {
        rows: e.rows.clone(),
        source: e.source,
        matrix: to_matrix(&e.matrix),
        mix: None,
    }
}

/// The bundle layout of a full geometry.
pub fn layout_of(scene: &Scene, g: &Geometry) -> Layout {
    let mut surfaces: Vec<SurfaceInfo> = Vec::new();
    for s in &g.surfaces {
        let n = s.n_texels as u32;
        match surfaces.last_mut() {
            // Clutter boxes: six faces, one surface name.
            Some(last) if last.name == s.name => last.texel_count += n,
            _ => surfaces.push(SurfaceInfo {
                name: s.name.clone(),
                texel_offset: s.texel_offset as u32,
                texel_count: n,
            }),
        }
    }
    let f3 = |v: [f64; 3]| v.map(|x| x as f32);
    let mut rects = Vec::new();
    let mut triangles = Vec::new();
    for p in &g.primitives {
        match p {
            Primitive::Rect {
                axis,
                coord,
                min,
                max,
                ..
            } => rects.push(bundle::Rect {
                axis: *axis as u8,
                coord: *coord as f32,
                min: min.map(|x| x as f32),
                max: max.map(|x| x as f32),
            }),
            Primitive::Triangle { v, .. } => triangles.push(v.map(f3)),
        }
    }
    Layout {
        scene_name: scene.name.clone(),
        surfaces,
        positions: g.texels.iter().map(|t| f3(t.position)).collect(),
        normals: g.texels.iter().map(|t| f3(t.normal)).collect(),
        albedo: g.texels.iter().map(|t| f3(t.albedo)).collect(),
        texel_size: g
            .texels
            .iter()
            .map(|t| {
                let s = &g.surfaces[t.surface as usize];
                match s.owner {
                    // A mesh texel: the side of the square in the normal's dominant tangent
                    // plane whose lift onto the texel's plane has the texel's area
                    // (`docs/bundle-format.md`, layout).
                    SurfaceOwner::ClutterMesh { atlas, .. } => {
                        let area = g.mesh_atlases[atlas].0.texels[t.index as usize].area;
                        let dominant = t.normal.iter().fold(0.0f64, |m, x| m.max(x.abs()));
                        let side = (area * dominant).sqrt() as f32;
                        [side, side]
                    }
                    _ => [
                        ((s.max[0] - s.min[0]) / s.t as f64) as f32,
                        ((s.max[1] - s.min[1]) / s.t as f64) as f32,
                    ],
                }
            })
            .collect(),
        rects,
        triangles,
    }
}

/// Each mesh surface's lightmap image (its atlas) for the bundle's layout.
pub fn surface_atlases_of(g: &Geometry, layout: &Layout) -> Vec<bundle::SurfaceAtlas> {
    g.mesh_atlases
        .iter()
        .map(|(atlas, surface)| {
            let name = &g.surfaces[*surface as usize].name;
            let index = layout
                .surfaces
                .iter()
                .position(|s| &s.name == name)
                .expect("every mesh surface is in the layout");
            bundle::SurfaceAtlas {
                surface: index as u32,
                width: atlas.width,
                height: atlas.height,
                texel_xy: atlas.texels.iter().map(|t| [t.x, t.y]).collect(),
            }
        })
        .collect()
}

/// The scene's blocks' shape operators, deduplicated by content key up to box symmetry: blocks
/// that are rotations or mirror images of one another share one canonical shape
/// (`ShapeSpec::canonical`), baked, cached and shipped once.
pub struct ShapePlan {
    /// One per block: its own spec, in its own frame.
    pub specs: Vec<ShapeSpec>,
    /// Unique canonical shape keys, in order of first use.
    pub unique: Vec<String>,
    /// Per unique shape, its canonical spec (what is baked and cached).
    pub unique_specs: Vec<ShapeSpec>,
    /// Per block, its unique shape.
    pub shape_index: Vec<usize>,
    /// Per block, the symmetry taking its frame to its shape's.
    pub symmetry: Vec<BoxSymmetry>,
}

impl ShapePlan {
    /// Per block, the key of the operators it applies: its shape's key, and the symmetry when
    /// it is not the identity (what the transport cache is keyed by).
    pub fn block_keys(&self) -> Vec<String> {
        self.shape_index
            .iter()
            .zip(&self.symmetry)
            .map(|(i, g)| g.instance_key(&self.unique[*i]))
            .collect()
    }

    /// Per block, the operators it applies, from the unique shapes' (`unique[i]` for shape
    /// `i`): the shape's own for an identity block, else the shape's seen through the block's
    /// symmetry, made once per distinct (shape, symmetry) and shared by the blocks using it.
    pub fn block_operators(&self, unique: &[Arc<ShapeOperators>]) -> Vec<Arc<ShapeOperators>> {
        let mut instances: HashMap<(usize, BoxSymmetry), Arc<ShapeOperators>> = HashMap::new();
        (0..self.specs.len())
            .map(|b| {
                let (shape, g) = (self.shape_index[b], self.symmetry[b]);
                if g.is_identity() {
                    return unique[shape].clone();
                }
                instances
                    .entry((shape, g))
                    .or_insert_with(|| {
                        Arc::new(instance_operators(&unique[shape], &self.specs[b], g))
                    })
                    .clone()
            })
            .collect()
    }
}

/// Which shape each block uses, and the unique shapes.
pub fn shape_plan(scene: &Scene) -> ShapePlan {
    let specs: Vec<ShapeSpec> = scene
        .blocks
        .iter()
        .map(|b| ShapeSpec::for_block(&b.aabb(), &b.open, &scene.settings, &scene.light_regions))
        .collect();
    let mut unique: Vec<String> = Vec::new();
    let mut unique_specs = Vec::new();
    let mut shape_index: Vec<usize> = Vec::new();
    let mut symmetry = Vec::new();
    let mut key_to_index: HashMap<String, usize> = HashMap::new();
    for spec in &specs {
        let (canonical, g) = spec.canonical();
        let key = canonical.key();
        let idx = *key_to_index.entry(key.clone()).or_insert_with(|| {
            unique.push(key);
            unique_specs.push(canonical);
            unique.len() - 1
        });
        shape_index.push(idx);
        symmetry.push(g);
    }
    ShapePlan {
        specs,
        unique,
        unique_specs,
        shape_index,
        symmetry,
    }
}

/// The MRT inter-block transport of the blocks alone (and its compaction when the scene ships
/// compact transport).
pub fn mrt_transport(
    scene: &Scene,
    block_geometry: &Geometry,
    per_block: &[&ShapeOperators],
    openings: &[[Option<lightfarm_proto::scene::Opening>; 6]],
    transport_kind: Transport,
    progress: &dyn Progress,
) -> Result<CachedTransport, BakeError> {
    let settings = &scene.settings;
    let (mrt, mut stats) = match transport_kind {
        Transport::Lightfield => {
            progress.stage("lightfield transport", 1);
            let (blocks, stats) = lightfield_transport(per_block, openings, settings.tolerance);
            progress.advance(1);
            (MrtTransport::Lightfield(blocks), stats)
        }
        Transport::Traced => {
            progress.stage("traced transport", block_geometry.texels.len() as u64);
            let tracer = Tracer::new(block_geometry.primitives.clone(), block_geometry.scale());
            let (blocks, stats) = traced_transport(
                block_geometry,
                &tracer,
                per_block,
                settings.rays_per_texel,
                settings.seed,
                settings.tolerance,
                &|n| progress.advance(n),
            );
            (MrtTransport::Traced(blocks), stats)
        }
    };
    let compact = if settings.compact_transport {
        let compact = compact_transport(per_block, &mrt, settings.tolerance)
            .map_err(|e| BakeError::Transport(e.to_string()))?;
        stats.compact_ranks = compact.iter().map(|c| c.y.ncols()).collect();
        Some(compact)
    } else {
        None
    };
    Ok(CachedTransport {
        mrt,
        compact,
        stats,
    })
}

/// A dynamic object's DNRT grid: from the cache, or baked and stored there.
pub fn dnrt_grid(
    scene: &Scene,
    scene_dir: &Path,
    object: &lightfarm_proto::scene::DynamicObject,
    cache: Option<&DnrtCache>,
) -> Result<lightfarm_proto::dnrt_grid::DnrtGrid, BakeError> {
    let settings = &scene.settings;
    let mesh = load_mesh(
        &format!("dynamic \"{}\"", object.id),
        scene_dir,
        &object.mesh,
        &Transform::default(),
    )
    .map_err(GeometryError::from)?;
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

/// Bakes a validated scene. `scene_dir` resolves mesh paths.
pub fn bake(
    scene: &Scene,
    scene_dir: &Path,
    options: &BakeOptions,
    progress: &dyn Progress,
) -> Result<(Bundle, BakeReport), BakeError> {
    scene.validate()?;
    let mut report = BakeReport::default();
    let mut timer = Instant::now();
    let mut lap = |report: &mut BakeReport, name: &str| {
        report
            .stage_seconds
            .push((name.to_string(), timer.elapsed().as_secs_f64()));
        timer = Instant::now();
    };
    let settings = &scene.settings;
    let full_geometry = Geometry::from_scene(scene, scene_dir)?;
    let block_geometry = Geometry::blocks_only(scene);
    let openings = scene.openings()?;
    report.blocks = scene.blocks.len();
    report.texels = full_geometry.texels.len();
    lap(&mut report, "geometry");

    // Shape operators, deduplicated by content key.
    let plan = shape_plan(scene);
    let ShapePlan {
        unique,
        unique_specs,
        shape_index,
        ..
    } = &plan;
    report.unique_shapes = unique.len();
    let mut shapes: Vec<Arc<ShapeOperators>> = Vec::new();
    let mut to_compute: Vec<usize> = Vec::new();
    let mut slots: Vec<Option<Arc<ShapeOperators>>> = vec![None; unique.len()];
    for (i, key) in unique.iter().enumerate() {
        match options.cache.as_ref().map(|c| c.get(key)) {
            Some(Lookup::Hit(ops)) => {
                report.shapes_from_cache += 1;
                slots[i] = Some(Arc::from(ops));
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
        let ops = bake_shape(&unique_specs[i], &|n| progress.advance(n))?;
        if let Some(cache) = &options.cache {
            cache.put(&ops)?;
        }
        report.shapes_computed += 1;
        slots[i] = Some(Arc::new(ops));
    }
    shapes.extend(
        slots
            .into_iter()
            .map(|s| s.expect("every shape is cached or computed")),
    );
    report.ranks = shapes.iter().map(|s| s.rank()).collect();
    lap(&mut report, "shape operators");

    let block_operators = plan.block_operators(&shapes);
    let per_block: Vec<&ShapeOperators> = block_operators.iter().map(|s| s.as_ref()).collect();
    // Inter-block transport: of the blocks alone, so cached by the blocks and their shapes.
    let transport_kind = options.transport.unwrap_or(settings.transport);
    let transport_cache = match &options.cache {
        Some(c) => Some(TransportCache::open(c.dir())?),
        None => None,
    };
    let block_shape_keys = plan.block_keys();
    let transport_key = transport_key(scene, transport_kind, &block_shape_keys);
    let cached = transport_cache.as_ref().and_then(|c| c.get(&transport_key));
    report.transport_from_cache = cached.is_some();
    let CachedTransport {
        mrt,
        compact,
        stats,
    } = match cached {
        Some(t) => t,
        None => {
            let computed = mrt_transport(
                scene,
                &block_geometry,
                &per_block,
                &openings,
                transport_kind,
                progress,
            )?;
            if let Some(cache) = &transport_cache {
                cache.put(&transport_key, &computed)?;
            }
            computed
        }
    };
    report.transport = stats;
    let transport = if let Some(compact) = &compact {
        TransportOps::Compact(
            compact
                .iter()
                .map(|c| bundle::CompactEntry {
                    target_block: c.target_block as u32,
                    sources: c.sources.iter().map(|s| *s as u32).collect(),
                    y: to_matrix(&c.y),
                    z: to_matrix(&c.z),
                })
                .collect(),
        )
    } else {
        match &mrt {
            MrtTransport::Lightfield(blocks) => TransportOps::Lightfield(
                blocks
                    .iter()
                    .map(|b| bundle::PropEntry {
                        target_block: b.target_block as u32,
                        target_face: b.target_face.index() as u8,
                        source_block: b.source_block as u32,
                        matrix: to_matrix(&b.matrix),
                    })
                    .collect(),
            ),
            MrtTransport::Traced(blocks) => TransportOps::Traced(
                blocks
                    .iter()
                    .map(|b| bundle::TracedEntry {
                        target_block: b.target_block as u32,
                        source_block: b.source_block as u32,
                        matrix: to_matrix(&b.matrix),
                    })
                    .collect(),
            ),
        }
    };
    // Opening operators are only applied by lightfield transport at run time.
    let ship_openings = matches!(transport, TransportOps::Lightfield(_));
    // The bundle grows in file order; each step's sections are final once announced.
    let layout = layout_of(scene, &full_geometry);
    let surface_atlases = surface_atlases_of(&full_geometry, &layout);
    let mut bundle = Bundle {
        surface_atlases,
        layout,
        shapes: shapes
            .iter()
            .map(|s| bundle::ShapeOps {
                key: s.key.clone(),
                u_b: to_matrix(&s.u_b),
                t_db: to_matrix(&s.t_db),
                openings: s
                    .openings
                    .iter()
                    .filter(|_| ship_openings)
                    .map(|o| bundle::OpeningOps {
                        face: o.face.index() as u8,
                        u_r: to_matrix(&o.u_r),
                    })
                    .collect(),
            })
            .collect(),
        blocks: scene
            .blocks
            .iter()
            .enumerate()
            .map(|(b, block)| bundle::BlockOps {
                symmetry: (!plan.symmetry[b].is_identity()).then(|| bundle::BlockSymmetry {
                    symmetry: plan.symmetry[b],
                    closed: bundle::BlockSymmetry::mask(&block.closed_faces()),
                }),
                id: block.id.clone(),
                shape: shape_index[b] as u32,
                texel_offset: full_geometry.block_texels[b].start as u32,
            })
            .collect(),
        transport: Some(transport),
        full: None,
        drt: None,
        probes: None,
        dnrt: None,
        sh: None,
    };
    let announce = |bundle: &Bundle| {
        if progress.wants_sections() {
            progress.sections_ready(bundle);
        }
    };
    announce(&bundle);
    lap(&mut report, "transport");

    // DRT: clutter operators.
    let drt_ops = if scene.clutter.is_empty() {
        None
    } else {
        let n = full_geometry.texels.len() as u64;
        progress.stage("clutter operators", n);
        let ray_cache = match &options.cache {
            Some(c) => Some(DrtRayCache::open(c.dir())?),
            None => None,
        };
        let ops = build_drt(
            scene,
            &openings,
            &full_geometry,
            &block_geometry,
            &per_block,
            &mrt,
            ray_cache.as_ref(),
            &|k| progress.advance(k),
        )
        .map_err(|source| BakeError::Drt(source.to_string()))?;
        report.drt = Some(ops.stats.clone());
        Some(ops)
    };
    bundle.drt = match &drt_ops {
        Some(ops) => {
            let (drt, stats) = drt_section(&bundle, ops, settings)?;
            report.delta_compaction = stats;
            Some(drt)
        }
        None => None,
    };
    if bundle.drt.is_some() {
        announce(&bundle);
    }
    lap(&mut report, "clutter operators");

    // U_dyn: the probe volume, when something will read it.
    let wanted = match settings.probe_volume {
        ProbeVolumeMode::Auto => !scene.dynamic.is_empty(),
        ProbeVolumeMode::Always => !(scene.clutter.is_empty() && scene.dynamic.is_empty()),
        ProbeVolumeMode::Never => false,
    };
    bundle.probes = if !wanted {
        None
    } else {
        let (clutter, projection_of): (&[_], Vec<Option<usize>>) = match &drt_ops {
            Some(ops) => (&ops.clutter, ops.projection_of.clone()),
            None => (&[], vec![None; scene.clutter.len()]),
        };
        let volume = build_probe_volume(
            scene,
            &full_geometry,
            &per_block,
            clutter,
            &projection_of,
            &|_| {},
        );
        report.probes = volume.n_probes;
        Some(bundle::ProbeVolume {
            origin: volume.origin.map(|x| x as f32),
            spacing: volume.spacing as f32,
            dims: volume.dims.map(|d| d as u32),
            slot: volume.slot,
            n_probes: volume.n_probes as u32,
            entries: volume.entries.iter().map(to_entry).collect(),
        })
    };
    if bundle.probes.is_some() {
        announce(&bundle);
    }
    lap(&mut report, "probe volume");

    // DNRT grids: one per dynamic object, content-cached (they depend on the object alone).
    bundle.dnrt = if scene.dynamic.is_empty() {
        None
    } else {
        let cache = match &options.cache {
            Some(c) => Some(DnrtCache::open(c.dir())?),
            None => None,
        };
        let mut grids = Vec::new();
        for object in &scene.dynamic {
            let start = Instant::now();
            let grid = dnrt_grid(scene, scene_dir, object, cache.as_ref())?;
            report.dnrt.push((
                object.id.clone(),
                start.elapsed().as_secs_f64(),
                grid.data_bytes(),
            ));
            grids.push(grid);
        }
        Some(grids)
    };
    if bundle.dnrt.is_some() && options.full {
        announce(&bundle);
    }
    lap(&mut report, "dnrt grids");

    // SH responses for normal-mapped surfaces, only when the scene asks for them.
    if settings.sh_responses {
        progress.stage("sh responses", full_geometry.texels.len() as u64);
        let (clutter, projection_of, buried): (&[_], Vec<Option<usize>>, &[u32]) = match &drt_ops {
            Some(ops) => (&ops.clutter, ops.projection_of.clone(), &ops.buried),
            None => (&[], vec![None; scene.clutter.len()], &[]),
        };
        let ops = build_sh_responses(
            scene,
            &full_geometry,
            &per_block,
            clutter,
            &projection_of,
            buried,
            &|k| progress.advance(k),
        )
        .map_err(|e| BakeError::Drt(format!("sh responses: {e}")))?;
        report.sh = Some(ops.stats.clone());
        bundle.sh = Some(bundle::ShResponses {
            entries: ops
                .entries
                .iter()
                .map(|e| bundle::ShEntry {
                    texels: e.texels.clone(),
                    source: e.source,
                    y: to_matrix(&e.y),
                    z: to_matrix(&e.z),
                })
                .collect(),
        });
        if options.full {
            announce(&bundle);
        }
        lap(&mut report, "sh responses");
    }

    // The dense Hašan-style operator over the full geometry.
    bundle.full = if options.full {
        progress.stage("dense operator", full_geometry.texels.len() as u64);
        let tracer = Tracer::new(full_geometry.primitives.clone(), full_geometry.scale());
        let all: Vec<usize> = (0..full_geometry.texels.len()).collect();
        let rows = gather_rows(
            &full_geometry,
            &tracer,
            &all,
            settings.rays_per_texel,
            settings.seed,
            Purpose::FullOperator,
            &|n| progress.advance(n),
        );
        let mut sparse = SparseRows {
            n: all.len() as u32,
            row_start: vec![0],
            cols: Vec::new(),
            values: Vec::new(),
        };
        for row in rows {
            for (c, v) in row {
                sparse.cols.push(c);
                sparse.values.push(v);
            }
            sparse.row_start.push(sparse.cols.len() as u32);
        }
        Some(sparse)
    } else {
        None
    };
    lap(&mut report, "dense operator");
    Ok((bundle, report))
}
