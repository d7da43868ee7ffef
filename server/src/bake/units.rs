//! A bake cut into deterministic units that fill the operator cache, for running on many
//! machines (the farm): each unit computes one cache entry (a shape's operators, a block's or a
//! clutter object's DRT rays, a dynamic object's DNRT grid, the level's transport), and the
//! bundle is then assembled by [`crate::bake::bake()`] over a cache holding every unit's
//! files — every lookup hits, so assembly is quick and its bundle is byte-identical to a bake
//! run in one piece (the cache never changes results).
//!
//! Phases: units of one phase are independent; phase 1 (transport) reads phase 0's shapes.
//! A unit run twice writes identical bytes, so a redelivered unit is harmless.
//!
//! Who calls it: the farm's workers (through the service), and tests. Paths are relative to
//! the operator cache directory (the one [`ShapeCache`] opens).
//!
//! A [`UnitScene`] holds what a scene's units share, made once per scene rather than once per
//! unit: the validation, the shape plan and the DRT ray pass's level (geometry, openings,
//! tracers). A farm worker plans a bake and runs its units one after another on one
//! `UnitScene`; at 1,000 blocks (1,338 units) remaking them per unit, three times for a DRT
//! unit, was most of the farm's time.

use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use lightfarm_proto::scene::{Opening, Scene};

use crate::bake::cache::dnrt::{dnrt_key, DnrtCache};
use crate::bake::cache::shape::{Lookup, ShapeCache};
use crate::bake::cache::transport::{transport_key, TransportCache};
use crate::bake::drt::rays::{trace_block_unit, trace_clutter_unit, DrtRayCache, RayPass};
use crate::bake::mrt::shape::{bake_shape, ShapeOperators};
use crate::bake::pipeline::plan::{shape_plan, ShapePlan};
use crate::bake::pipeline::stages::{dnrt_grid, mrt_transport, SplitShapes};
use crate::bake::progress::Progress;
use crate::bake::scene::geometry::{Geometry, GeometryError};
use crate::bake::scene::mesh::load_mesh;
use crate::bake::scene::pieces::baked_scene;
use crate::bake::tracer::Tracer;
use crate::bake::BakeError;

/// One deterministic piece of a bake.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum BakeUnit {
    /// Unique shape `index` of the scene's [`ShapePlan`].
    Shape { index: usize },
    /// The level's MRT inter-block transport (needs every shape).
    Transport,
    /// Block `block`'s DRT rays.
    DrtBlock { block: usize },
    /// Box clutter `clutter`'s DRT rays.
    DrtClutter { clutter: usize },
    /// Dynamic object `object`'s DNRT grid.
    Dnrt { object: usize },
}

impl BakeUnit {
    /// `shape/3`, `transport`, `drt-block/5`, `drt-clutter/0`, `dnrt/1`.
    pub fn name(&self) -> String {
        match self {
            BakeUnit::Shape { index } => format!("shape/{index}"),
            BakeUnit::Transport => "transport".to_string(),
            BakeUnit::DrtBlock { block } => format!("drt-block/{block}"),
            BakeUnit::DrtClutter { clutter } => format!("drt-clutter/{clutter}"),
            BakeUnit::Dnrt { object } => format!("dnrt/{object}"),
        }
    }

    /// The inverse of [`BakeUnit::name`].
    pub fn parse(name: &str) -> Option<BakeUnit> {
        if name == "transport" {
            return Some(BakeUnit::Transport);
        }
        let (kind, index) = name.split_once('/')?;
        let i: usize = index.parse().ok()?;
        Some(match kind {
            "shape" => BakeUnit::Shape { index: i },
            "drt-block" => BakeUnit::DrtBlock { block: i },
            "drt-clutter" => BakeUnit::DrtClutter { clutter: i },
            "dnrt" => BakeUnit::Dnrt { object: i },
            _ => return None,
        })
    }
}

/// The level a DRT unit traces: the scene's geometry with and without clutter, its openings and
/// both tracers (what [`RayPass::new`] borrows).
struct RayLevel {
    g: Geometry,
    gb: Geometry,
    openings: Vec<[Option<Opening>; 6]>,
    tracer: Tracer,
    block_tracer: Tracer,
}

/// A validated scene and what its units share (module doc): its files' directory, the shape
/// plan, and the ray pass's level, made on the first DRT unit and kept.
pub struct UnitScene {
    scene: Scene,
    dir: PathBuf,
    shapes: ShapePlan,
    rays: Mutex<Option<Arc<RayLevel>>>,
}

impl UnitScene {
    /// Validates `scene` (its mesh files under `scene_dir`) and makes its shape plan.
    pub fn new(scene: Scene, scene_dir: &Path) -> Result<UnitScene, BakeError> {
        scene.validate()?;
        // Long blocks are baked as pieces (`scene::pieces`), as `bake` does.
        // A scene with nothing to cut is kept as it is, not copied.
        let cut = match baked_scene(&scene) {
            Cow::Owned(cut) => Some(cut),
            Cow::Borrowed(_) => None,
        };
        let scene = cut.unwrap_or(scene);
        let shapes = shape_plan(&scene);
        Ok(UnitScene {
            scene,
            dir: scene_dir.to_path_buf(),
            shapes,
            rays: Mutex::new(None),
        })
    }

    /// The ray pass over the scene's level (made on first use, then shared) handed to `f`.
    fn with_ray_pass<T>(&self, f: impl FnOnce(&RayPass) -> T) -> Result<T, BakeError> {
        let level = {
            let mut slot = self.rays.lock().unwrap_or_else(|p| p.into_inner());
            match &*slot {
                Some(level) => level.clone(),
                None => {
                    let g = Geometry::from_scene(&self.scene, &self.dir)?;
                    let gb = Geometry::blocks_only(&self.scene);
                    let openings = self.scene.openings()?;
                    let tracer = Tracer::new(g.primitives.clone(), g.scale());
                    let block_tracer = Tracer::new(gb.primitives.clone(), gb.scale());
                    let level = Arc::new(RayLevel {
                        g,
                        gb,
                        openings,
                        tracer,
                        block_tracer,
                    });
                    *slot = Some(level.clone());
                    level
                }
            }
        };
        let pass = RayPass::new(
            &self.scene,
            &level.openings,
            &level.g,
            &level.gb,
            &level.tracer,
            &level.block_tracer,
        );
        Ok(f(&pass))
    }
}

/// The scene's units by phase: phase 0 shapes, DRT rays and DNRT grids; phase 1 transport.
pub fn plan(us: &UnitScene) -> Result<Vec<Vec<BakeUnit>>, BakeError> {
    let (scene, shapes) = (&us.scene, &us.shapes);
    let mut first: Vec<BakeUnit> = (0..shapes.unique.len())
        .map(|index| BakeUnit::Shape { index })
        .collect();
    if !scene.clutter.is_empty() {
        // Blocks and clutter objects with texels, each a unit.
        let (blocks, clutter) = us.with_ray_pass(|pass| {
            let g = pass.geometry();
            let with_texels = |ranges: &[std::ops::Range<usize>]| -> Vec<usize> {
                (0..ranges.len())
                    .filter(|&k| !ranges[k].is_empty())
                    .collect()
            };
            (with_texels(&g.block_texels), with_texels(&g.clutter_texels))
        })?;
        first.extend(blocks.into_iter().map(|block| BakeUnit::DrtBlock { block }));
        first.extend(
            clutter
                .into_iter()
                .map(|clutter| BakeUnit::DrtClutter { clutter }),
        );
    }
    first.extend((0..scene.dynamic.len()).map(|object| BakeUnit::Dnrt { object }));
    Ok(vec![first, vec![BakeUnit::Transport]])
}

fn unknown(unit: &BakeUnit) -> BakeError {
    BakeError::Drt(format!("unit {} is not part of this scene", unit.name()))
}

/// A shape's two cache files: its operators and its lightfields.
fn shape_files(key: &str) -> [PathBuf; 2] {
    [
        crate::bake::cache::shape::ENTRY.relative_path(key),
        crate::bake::cache::shape::LIGHTFIELD_ENTRY.relative_path(key),
    ]
}

/// Cache files a unit reads if present: its own earlier result (reused, or refreshed
/// incrementally) and, for transport, every shape.
pub fn unit_inputs(us: &UnitScene, unit: &BakeUnit) -> Result<Vec<PathBuf>, BakeError> {
    let (scene, shapes) = (&us.scene, &us.shapes);
    Ok(match unit {
        BakeUnit::Shape { index } => {
            shape_files(shapes.unique.get(*index).ok_or_else(|| unknown(unit))?).to_vec()
        }
        BakeUnit::Transport => {
            let mut files: Vec<PathBuf> =
                shapes.unique.iter().flat_map(|k| shape_files(k)).collect();
            files.push(transport_file(scene, shapes));
            files
        }
        BakeUnit::DrtBlock { .. } | BakeUnit::DrtClutter { .. } | BakeUnit::Dnrt { .. } => {
            outputs(us, unit)?
        }
    })
}

fn transport_file(scene: &Scene, shapes: &ShapePlan) -> PathBuf {
    let keys = shapes.block_keys();
    crate::bake::cache::transport::ENTRY.relative_path(&transport_key(
        scene,
        scene.settings.transport,
        &keys,
    ))
}

/// The cache files holding a unit's result.
fn outputs(us: &UnitScene, unit: &BakeUnit) -> Result<Vec<PathBuf>, BakeError> {
    let (scene, shapes) = (&us.scene, &us.shapes);
    Ok(match unit {
        BakeUnit::Shape { index } => {
            shape_files(shapes.unique.get(*index).ok_or_else(|| unknown(unit))?).to_vec()
        }
        BakeUnit::Transport => vec![transport_file(scene, shapes)],
        BakeUnit::DrtBlock { block } => {
            if *block >= scene.blocks.len() {
                return Err(unknown(unit));
            }
            us.with_ray_pass(|pass| vec![pass.block_unit_file(*block)])?
        }
        BakeUnit::DrtClutter { clutter } => {
            if *clutter >= scene.clutter.len() {
                return Err(unknown(unit));
            }
            us.with_ray_pass(|pass| pass.clutter_unit_file(*clutter).into_iter().collect())?
        }
        BakeUnit::Dnrt { object } => {
            let object = scene.dynamic.get(*object).ok_or_else(|| unknown(unit))?;
            let mesh = load_mesh(
                &format!("dynamic \"{}\"", object.id),
                &us.dir,
                &object.mesh,
                &Default::default(),
            )
            .map_err(GeometryError::from)?;
            let key = dnrt_key(
                &mesh.triangles,
                object.albedo,
                &mesh.albedo,
                &scene.settings.dnrt,
                scene.settings.seed,
            );
            vec![crate::bake::cache::dnrt::ENTRY.relative_path(&key)]
        }
    })
}

/// Runs one unit against the cache; returns the cache files holding its result.
pub fn run_unit(
    us: &UnitScene,
    cache: &ShapeCache,
    unit: &BakeUnit,
    progress: &dyn Progress,
) -> Result<Vec<PathBuf>, BakeError> {
    let (scene, scene_dir, shapes) = (&us.scene, us.dir.as_path(), &us.shapes);
    match unit {
        BakeUnit::Shape { index } => {
            let key = shapes.unique.get(*index).ok_or_else(|| unknown(unit))?;
            if !matches!(cache.get(key), Lookup::Hit(_)) {
                let spec = &shapes.unique_specs[*index];
                progress.stage("shape operators", spec.n_texels() as u64);
                let ops = bake_shape(spec, &|n| progress.advance(n))?;
                cache.put(&ops)?;
            }
        }
        BakeUnit::Transport => {
            let transport_cache = TransportCache::open(cache.dir())?;
            let keys = shapes.block_keys();
            let key = transport_key(scene, scene.settings.transport, &keys);
            if transport_cache.get(&key).is_none() {
                let mut unique: Vec<ShapeOperators> = Vec::new();
                for k in &shapes.unique {
                    match cache.get(k) {
                        Lookup::Hit(ops) => unique.push(*ops),
                        _ => {
                            return Err(BakeError::Drt(format!(
                                "transport needs shape {k}, which is not in the cache"
                            )))
                        }
                    }
                }
                let mut unique = SplitShapes::new(unique);
                let lightfields = std::mem::take(&mut unique.lightfields)
                    .into_iter()
                    .map(|l| l.expect("a whole cached shape has its lightfields"))
                    .collect();
                // Stored target by target (the unit's output is the entry).
                mrt_transport(
                    scene,
                    &shapes,
                    &Geometry::blocks_only(scene),
                    &unique.operators,
                    lightfields,
                    &scene.openings()?,
                    scene.settings.transport,
                    (&transport_cache, key.as_str()),
                    progress,
                )?;
            }
        }
        BakeUnit::DrtBlock { block } => {
            if *block >= scene.blocks.len() {
                return Err(unknown(unit));
            }
            let ray_cache = DrtRayCache::open(cache.dir())?;
            us.with_ray_pass(|pass| {
                progress.stage("clutter operators", pass.block_texel_count(*block) as u64);
                trace_block_unit(pass, *block, Some(&ray_cache), &|n| progress.advance(n))
            })??;
        }
        BakeUnit::DrtClutter { clutter } => {
            if *clutter >= scene.clutter.len() {
                return Err(unknown(unit));
            }
            let ray_cache = DrtRayCache::open(cache.dir())?;
            us.with_ray_pass(|pass| {
                progress.stage(
                    "clutter operators",
                    pass.clutter_texel_count(*clutter) as u64,
                );
                trace_clutter_unit(pass, *clutter, Some(&ray_cache), &|n| progress.advance(n))
            })??;
        }
        BakeUnit::Dnrt { object } => {
            let object = scene.dynamic.get(*object).ok_or_else(|| unknown(unit))?;
            progress.stage("dnrt grids", 1);
            dnrt_grid(
                scene,
                scene_dir,
                object,
                Some(&DnrtCache::open(cache.dir())?),
            )?;
            progress.advance(1);
        }
    }
    outputs(us, unit)
}
