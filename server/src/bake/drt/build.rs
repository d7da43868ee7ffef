//! Delta Radiance Transfer (paper 000 §4–§5): the scene-dependent operators that add clutter to
//! MRT, built by ray tracing against the real geometry.
//!
//! - **ΔU_b, delta occlusion (§4.1):** a block texel's rays that hit clutter continue (through the
//!   empty blocks) to the wall behind, and subtract `L_imp` there — antiradiance. Source: any
//!   block the continued ray lands in, so texels in other blocks that see the clutter get rows.
//! - **ΔU_c, delta reflection (§4.2):** the same rays read the clutter's direct-light basis
//!   `B_j` at the clutter texel they hit: `+ ΔU_c c_j` with `c_j = B_jᵀ l_d`.
//! - **C_b, clutter gather (§4.3),** and clutter-to-clutter bounce (ours): a clutter texel's rays
//!   read `L_imp` of the block texel they hit, or `B_j'` of another clutter object's texel.
//! - **Exact scene gather (ours, `scene_gather: exact`):** a block texel that gets rows instead
//!   gets a gather over the direct light of the texels its cosine rays hit, and its MRT light is
//!   dropped (`replaced`): near clutter its light is then exact to one bounce, MRT's own error
//!   included. Buried texels next to gathered ones copy the first such neighbour's gather.
//! - **Transport inpainting (§5):** texels buried inside clutter get the average of their valid
//!   neighbours' shadowed transport minus their own unshadowed transport
//!   ([`crate::bake::drt::inpaint`]).
//!
//! In data-flow order: [`build_drt`] reads [`DrtInputs`], makes the clutter bases, traces (or
//! reuses) both ray passes, turns block texels' rays into rows (`BlockRows`), inpaints the
//! buried ones, turns clutter texels' rays into rows (`ClutterRows`), assembles the exact
//! gather with its few-hit entries pooled by tile ([`crate::bake::drt::tiles`]) and packs the
//! rows into [`DeltaBlock`]s by (target, source).
//!
//! Clutter texels are a box's six faces or a mesh's lightmap atlas (`mesh_atlas`); every
//! operator here reads them by global texel index, so both kinds go through the same code. A
//! clutter object's basis is placed around its box, or around a mesh's bounding box.
//!
//! Model only what the scene needs: a block texel whose rays hit clutter less often than the
//! tolerance gets no row (counted in the report). All operators are albedo-free.
//!
//! Invariant: deterministic per texel stream; rows are global texel indices, ascending.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use faer::Mat;
use rayon::prelude::*;

use lightfarm_proto::bundle::{DeltaSource, TexelGather};
use lightfarm_proto::scene::{Aabb, ClutterBasis, ClutterGather, Opening, Scene, SceneGather};

use crate::bake::drt::clutter_basis::{clutter_basis, prior_lights, ClutterBasisOps};
use crate::bake::drt::error::DrtError;
use crate::bake::drt::inpaint::inpaint;
use crate::bake::drt::lit_source::LitSource;
use crate::bake::drt::rays::{
    clutter_basis_unit, trace_all, BlockTexelRays, ClutterTexelRays, DrtRayCache, RayPass,
    RayPassResults,
};
use crate::bake::drt::rows::{add_row, RowMajor, RowsBySource};
use crate::bake::drt::tiles::TilePool;
use crate::bake::mrt::shape::ShapeOperators;
use crate::bake::scene::geometry::Geometry;
use crate::bake::tracer::Tracer;
use crate::bake::transport::source::TransportSource;

/// A delta operator block in f64.
pub struct DeltaBlock {
    pub rows: Vec<u32>,
    pub source: DeltaSource,
    pub matrix: Mat<f64>,
}

/// A clutter object's basis and where its texels are.
pub struct ClutterProjection {
    pub id: String,
    pub texel_offset: usize,
    pub basis: ClutterBasisOps,
}

/// Figures about the DRT build.
#[derive(Clone, Debug, Default)]
pub struct DrtStats {
    pub scene_texels_with_rows: usize,
    pub scene_texels_skipped: usize,
    pub buried_scene_texels: usize,
    pub buried_clutter_texels: usize,
    pub inpainted_without_neighbours: usize,
    /// With `scene_gather: exact`: block texels whose MRT light the exact gather replaces
    /// (texels with rows, and buried texels that copy a gathered neighbour's row).
    pub scene_texels_gathered: usize,
    pub clutter_ranks: Vec<usize>,
    /// Texels whose rays were traced in this bake, and texels whose rays an earlier bake's
    /// cache gave (incremental rebake).
    pub traced_texels: usize,
    pub reused_texels: usize,
    /// Block texels that cannot see any clutter through the openings: not traced.
    pub culled_texels: usize,
}

/// All DRT operators of a scene.
pub struct DrtOperators {
    /// Exact clutter gather (None with `clutter_gather: implicit`).
    pub direct_gather: Option<TexelGather>,
    pub clutter: Vec<ClutterProjection>,
    /// Scene clutter index → index in `clutter` (None for an object without texels).
    pub projection_of: Vec<Option<usize>>,
    pub entries: Vec<DeltaBlock>,
    pub buried: Vec<u32>,
    /// Block texels whose MRT light the gather replaces (`scene_gather: exact`), ascending.
    pub replaced: Vec<u32>,
    pub stats: DrtStats,
}

/// What the DRT build reads (all borrowed from the bake's earlier stages).
pub struct DrtInputs<'a> {
    pub scene: &'a Scene,
    /// Per block, its openings by face.
    pub openings: &'a [[Option<Opening>; 6]],
    /// The full geometry: blocks first, then clutter.
    pub geometry: &'a Geometry,
    /// The blocks-only geometry, with the same block texel indices.
    pub block_geometry: &'a Geometry,
    /// Per block, its shape's operators: their ranks for every block, `U_b` and the openings'
    /// `U_r` for the blocks inpainting reads (a bake may have emptied the others').
    pub shapes: &'a [&'a ShapeOperators],
    /// Per block, its `L_imp` row-major ([`l_imp_rows`]): what a hit on a block texel reads.
    pub l_imp_rows: &'a [Arc<RowMajor>],
    /// The blocks' MRT transport (what inpainting cancels on buried texels): at least the
    /// operators into the blocks [`crate::bake::drt::inpaint::inpainting_targets`] marks (a
    /// bake keeps no others); only those into blocks holding a buried texel are read.
    pub mrt: &'a dyn TransportSource,
}

/// Which object owns each global texel: blocks `0..n_blocks`, then clutter `n_blocks + c`.
struct TexelOwners<'a> {
    geometry: &'a Geometry,
    n_blocks: usize,
    owner: Vec<u32>,
}

impl<'a> TexelOwners<'a> {
    fn new(geometry: &'a Geometry, n_blocks: usize) -> TexelOwners<'a> {
        let mut owner = vec![u32::MAX; geometry.texels.len()];
        for (b, r) in geometry.block_texels.iter().enumerate() {
            for t in r.clone() {
                owner[t] = b as u32;
            }
        }
        for (c, r) in geometry.clutter_texels.iter().enumerate() {
            for t in r.clone() {
                owner[t] = (n_blocks + c) as u32;
            }
        }
        TexelOwners {
            geometry,
            n_blocks,
            owner,
        }
    }

    /// The owner of global texel `t` and `t`'s index within it.
    fn local(&self, t: u32) -> (usize, usize) {
        let owner = self.owner[t as usize] as usize;
        if owner < self.n_blocks {
            (owner, t as usize - self.geometry.block_texels[owner].start)
        } else {
            (
                owner,
                t as usize - self.geometry.clutter_texels[owner - self.n_blocks].start,
            )
        }
    }
}

/// The buried-texel tests: inside a (closed) clutter box, or outside every block.
///
/// A clutter texel is buried when the point just off its surface (along its normal, by
/// [`Burial::off`]) lies outside every (closed) block or inside another clutter object's
/// (closed) box, or when most of its rays hit back faces: a face pressed against a wall, the
/// floor or another prop (stacked or touching crates), or left outside the level. No light
/// reaches such a face, so it gets no rows and its light is 0, as a path tracer finds (its rays
/// start inside what covers it, where they may meet a wall that box is flush with and gather
/// the wall's light). A texel on an opening between two blocks is inside the level (closed
/// blocks), so a prop standing in a doorway keeps its light.
struct Burial<'a> {
    scene: &'a Scene,
    /// Tolerance, relative to the geometry's scale. `scale()` passes over every primitive:
    /// computed once, not per texel and object (which made this test quadratic in the level's
    /// size).
    e: f64,
}

impl Burial<'_> {
    fn inside_box(&self, p: [f64; 3], skip: Option<usize>) -> bool {
        let e = self.e;
        self.scene.clutter.iter().enumerate().any(|(c, object)| {
            if Some(c) == skip {
                return false;
            }
            let Some(b) = object.box_ else { return false };
            (0..3).all(|k| p[k] >= b.min[k] - e && p[k] <= b.max[k] + e)
        })
    }

    /// Whether `p` lies in some block, its faces included (within the tolerance).
    fn inside_closed_blocks(&self, p: [f64; 3]) -> bool {
        let e = self.e;
        self.scene
            .blocks
            .iter()
            .any(|b| (0..3).all(|k| p[k] >= b.min[k] - e && p[k] <= b.max[k] + e))
    }

    /// How far off its surface a clutter texel is tested: a hundred tolerances, so a face
    /// flush with a wall tests a point beyond the wall's tolerance.
    fn off(&self) -> f64 {
        100.0 * self.e
    }

    /// Whether the clutter texel at `p` with normal `n` on scene clutter object `own` is
    /// buried (see [`Burial`]); `back` is the weight of its rays that hit back faces.
    fn clutter_texel_buried(&self, p: [f64; 3], n: [f64; 3], own: usize, back: f64) -> bool {
        let q = [0, 1, 2].map(|k| p[k] + self.off() * n[k]);
        !self.inside_closed_blocks(q) || self.inside_box(q, Some(own)) || back > 0.5
    }
}

/// Builds the DRT operators from both ray passes, reusing what `cache` holds from an earlier
/// bake where nothing a texel's rays saw has changed; `progress` counts texels traced.
pub fn build_drt(
    inputs: &DrtInputs,
    cache: Option<&DrtRayCache>,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<DrtOperators, DrtError> {
    let (scene, g, gb) = (inputs.scene, inputs.geometry, inputs.block_geometry);
    let settings = &scene.settings;
    let tracer = Tracer::new(g.primitives.clone(), g.scale());
    let block_tracer = Tracer::new(gb.primitives.clone(), gb.scale());
    let n_blocks = scene.blocks.len();
    let owners = TexelOwners::new(g, n_blocks);

    let mut stats = DrtStats::default();
    // The clutter bases and both ray passes (block texels guided toward clutter; clutter
    // texels, reusing what an earlier bake traced where nothing it saw has changed) read only
    // the geometry: side by side, so that one object's basis does not leave a core idle.
    let pass = RayPass::new(scene, inputs.openings, g, gb, &tracer, &block_tracer);
    let (clutter, rays) = rayon::join(
        || clutter_projections(inputs, &tracer, cache, &mut stats),
        || trace_all(&pass, cache, progress),
    );
    let (clutter, rays) = (clutter?, rays?);
    // Scene clutter index → index in the bundle's clutter list (objects with texels).
    let projection_of: Vec<Option<usize>> = (0..scene.clutter.len())
        .map(|c| clutter.iter().position(|(k, _)| *k == c))
        .collect();
    let burial = Burial {
        scene,
        e: 1e-6 * g.scale(),
    };
    stats.traced_texels = rays.traced_texels;
    stats.reused_texels = rays.reused_texels;
    stats.culled_texels = rays.culled_texels;
    // The rays are the largest thing a DRT bake holds: each pass below consumes its own, so
    // their hit lists are freed (or moved into the gather) as the rows that replace them grow.
    let RayPassResults {
        block: block_rays,
        clutter: clutter_rays,
        ..
    } = rays;

    let rows = SourceRows {
        l_imp: inputs.l_imp_rows.to_vec(),
        basis: clutter
            .iter()
            .map(|(_, p)| RowMajor::of(&p.basis.basis))
            .collect(),
        projection_of: &projection_of,
        owners: &owners,
    };
    let widths: Vec<usize> = clutter.iter().map(|(_, p)| p.basis.basis.ncols()).collect();

    let mut blocks = block_texel_rows(inputs, block_rays, &rows, &burial, &mut stats);
    inpaint(
        inputs,
        &widths,
        &mut blocks.per_target,
        &blocks.buried,
        &mut blocks.gathered,
        &mut stats.inpainted_without_neighbours,
    )?;
    let clutter_rows = clutter_texel_rows(inputs, clutter_rays, &rows, &burial, &mut stats);

    // Block texel rows first (they precede clutter texels, so rows stay ascending), each row
    // freed once copied; the arrays are sized first (growing them by doubling held up to twice
    // their size, and both copies while moving).
    let n_rows = blocks.gathered.len() + clutter_rows.gathered.len();
    let n_entries = blocks.gathered.values().map(Vec::len).sum::<usize>()
        + clutter_rows
            .gathered
            .iter()
            .map(|(_, r)| r.len())
            .sum::<usize>();
    let mut gather = TexelGather {
        rows: Vec::with_capacity(n_rows),
        row_start: Vec::with_capacity(n_rows + 1),
        cols: Vec::with_capacity(n_entries),
        values: Vec::with_capacity(n_entries),
        tiles: Default::default(),
    };
    gather.row_start.push(0);
    let inv = 1.0 / settings.rays_per_texel as f64;
    stats.scene_texels_gathered = blocks.gathered.len();
    let replaced: Vec<u32> = blocks.gathered.keys().copied().collect();
    // Few-hit entries read their tile's mean direct light (`tiles`).
    let mut tiles = TilePool::new(g);
    for (x, mut hits) in blocks.gathered.into_iter().chain(clutter_rows.gathered) {
        tiles.pool(&mut hits);
        gather.rows.push(x);
        for (t, n) in hits {
            gather.cols.push(t);
            gather.values.push((n as f64 * inv) as f32);
        }
        gather.row_start.push(gather.cols.len() as u32);
    }
    tiles.finish(&mut gather);
    let mut buried = clutter_rows.buried;
    for (x, b) in blocks.buried.iter().enumerate() {
        if *b {
            buried.push(x as u32);
        }
    }
    buried.sort_unstable();

    let exact_scene = settings.scene_gather == SceneGather::Exact;
    let exact = settings.clutter_gather == ClutterGather::Exact;
    Ok(DrtOperators {
        direct_gather: (exact || exact_scene).then_some(gather),
        replaced,
        clutter: clutter.into_iter().map(|(_, p)| p).collect(),
        projection_of,
        entries: pack_entries(blocks.per_target, clutter_rows.per_clutter),
        buried,
        stats,
    })
}

/// Each clutter object's basis (scene clutter index, projection), for objects with texels.
fn clutter_projections(
    inputs: &DrtInputs,
    tracer: &Tracer,
    cache: Option<&DrtRayCache>,
    stats: &mut DrtStats,
) -> Result<Vec<(usize, ClutterProjection)>, DrtError> {
    let (scene, g) = (inputs.scene, inputs.geometry);
    // One object per worker (each basis is sequential inside), taken in scene order.
    let made: Vec<Option<(usize, ClutterProjection)>> = (0..scene.clutter.len())
        .into_par_iter()
        .map(|c| -> Result<_, DrtError> {
            let object = &scene.clutter[c];
            let range = g.clutter_texels[c].clone();
            if range.is_empty() {
                return Ok(None);
            }
            // The box, or the mesh's bounds (where prior lights are placed around it).
            let bounds = g.clutter_shapes[c].bounds;
            let aabb = object.box_.unwrap_or(Aabb {
                min: bounds[0],
                max: bounds[1],
            });
            let basis = if scene.settings.clutter_basis == ClutterBasis::Prior {
                let lights = prior_lights(scene, inputs.openings, c, &aabb);
                clutter_basis_unit(scene, g, c, &lights, cache, || {
                    clutter_basis(scene, inputs.openings, g, tracer, c, &aabb, range.clone())
                })?
            } else {
                clutter_basis(scene, inputs.openings, g, tracer, c, &aabb, range.clone())?
            };
            Ok(Some((
                c,
                ClutterProjection {
                    id: object.id.clone(),
                    texel_offset: range.start,
                    basis,
                },
            )))
        })
        .collect::<Result<_, _>>()?;
    let clutter: Vec<(usize, ClutterProjection)> = made.into_iter().flatten().collect();
    stats
        .clutter_ranks
        .extend(clutter.iter().map(|(_, p)| p.basis.basis.ncols()));
    Ok(clutter)
}

/// Row-major copies of every block's `L_imp`, one per distinct shape (blocks sharing a shape
/// share the copy), the distinct shapes copied one per core.
pub fn l_imp_rows(shapes: &[&ShapeOperators]) -> Vec<Arc<RowMajor>> {
    // Distinct shapes (by address) in first-use order, and each block's among them.
    let mut index: HashMap<*const ShapeOperators, usize> = HashMap::new();
    let mut distinct: Vec<&ShapeOperators> = Vec::new();
    let which: Vec<usize> = shapes
        .iter()
        .map(|&s| {
            *index.entry(s as *const ShapeOperators).or_insert_with(|| {
                distinct.push(s);
                distinct.len() - 1
            })
        })
        .collect();
    let rows: Vec<Arc<RowMajor>> = distinct
        .par_iter()
        .map(|s| Arc::new(RowMajor::of(&s.l_imp)))
        .collect();
    which.into_iter().map(|d| rows[d].clone()).collect()
}

/// What a hit reads: the `L_imp` row of a block texel, or the basis row of a clutter texel.
struct SourceRows<'a> {
    l_imp: Vec<Arc<RowMajor>>,
    basis: Vec<RowMajor>,
    /// Scene clutter index → index in the DRT clutter list.
    projection_of: &'a [Option<usize>],
    owners: &'a TexelOwners<'a>,
}

/// What the block-texel pass produced.
struct BlockRows {
    /// Per target block: its rows by source.
    per_target: Vec<RowsBySource>,
    /// Per global texel: buried (inside clutter, or its rays left through a back face).
    buried: Vec<bool>,
    /// `scene_gather: exact`: block texel → the lit texels its cosine rays hit (rays each).
    gathered: BTreeMap<u32, Vec<(u32, u32)>>,
}

/// ΔU_b and ΔU_c rows of block texels that see clutter (or, with `scene_gather: exact`, their
/// gathers); buried texels are marked for [`inpaint`]. Each target block's rows are built on a
/// worker of their own (a block's rows go to its own map), in texel order as one pass would,
/// consuming that block's rays (`rays[b]`, the block's texels in order).
fn block_texel_rows(
    inputs: &DrtInputs,
    rays: Vec<Vec<BlockTexelRays>>,
    rows: &SourceRows,
    burial: &Burial,
    stats: &mut DrtStats,
) -> BlockRows {
    let g = inputs.geometry;
    let n_blocks = inputs.scene.blocks.len();
    debug_assert_eq!(rays.len(), n_blocks);
    let per_block: Vec<TargetRows> = rays
        .into_par_iter()
        .enumerate()
        .map(|(b, r)| target_rows(inputs, b, r, rows, burial))
        .collect();
    let mut out = BlockRows {
        per_target: Vec::with_capacity(n_blocks),
        buried: vec![false; g.texels.len()],
        gathered: BTreeMap::new(),
    };
    for (b, t) in per_block.into_iter().enumerate() {
        let start = g.block_texels[b].start;
        out.buried[start..start + t.buried.len()].copy_from_slice(&t.buried);
        out.per_target.push(t.rows);
        out.gathered.extend(t.gathered);
        stats.buried_scene_texels += t.buried_count;
        stats.scene_texels_skipped += t.skipped;
        stats.scene_texels_with_rows += t.with_rows;
    }
    out
}

/// One target block's part of [`BlockRows`], with its counts.
struct TargetRows {
    rows: RowsBySource,
    /// Per texel of the block.
    buried: Vec<bool>,
    gathered: BTreeMap<u32, Vec<(u32, u32)>>,
    buried_count: usize,
    skipped: usize,
    with_rows: usize,
}

/// Block `target`'s rows from its texels' rays (`rays`, in the block's texel order), each
/// texel's freed once used (its hits moved into the gather with `scene_gather: exact`).
fn target_rows(
    inputs: &DrtInputs,
    target: usize,
    rays: Vec<BlockTexelRays>,
    rows: &SourceRows,
    burial: &Burial,
) -> TargetRows {
    let (scene, g) = (inputs.scene, inputs.geometry);
    let n_blocks = scene.blocks.len();
    let exact_scene = scene.settings.scene_gather == SceneGather::Exact;
    let first = g.block_texels[target].start;
    let mut out = TargetRows {
        rows: BTreeMap::new(),
        buried: vec![false; rays.len()],
        gathered: BTreeMap::new(),
        buried_count: 0,
        skipped: 0,
        with_rows: 0,
    };
    for (i, r) in rays.into_iter().enumerate() {
        let x = first + i;
        let buried = burial.inside_box(g.texels[x].position, None) || r.back_hits > 0.5;
        out.buried[i] = buried;
        if buried {
            out.buried_count += 1;
            continue;
        }
        if !r.sees_clutter(scene.settings.tolerance) {
            out.skipped += 1;
            continue;
        }
        out.with_rows += 1;
        if exact_scene {
            // The gather replaces MRT and the deltas on this texel.
            out.gathered.insert(x as u32, r.hits);
            continue;
        }
        for &(t, w) in &r.occluded {
            let (source, l) = rows.owners.local(t);
            // Antiradiance: −L_imp at the wall behind.
            add_row(
                &mut out.rows,
                LitSource::Block(source as u32),
                x as u32,
                rows.l_imp[source].row(l),
                -w,
            );
        }
        for &(k, w) in &r.reflected {
            let (owner, l) = rows.owners.local(k);
            let c = owner - n_blocks;
            if let Some(i) = rows.projection_of[c] {
                add_row(
                    &mut out.rows,
                    LitSource::Clutter(i as u32),
                    x as u32,
                    rows.basis[i].row(l),
                    w,
                );
            }
        }
    }
    out
}

/// What the clutter-texel pass produced.
struct ClutterRows {
    /// C_b and clutter-to-clutter rows of clutter texels (implicit gather).
    per_clutter: RowsBySource,
    /// `clutter_gather: exact`: per clutter texel with hits, its sparse row over the direct
    /// light of the texels hit, ascending by texel.
    gathered: Vec<(u32, Vec<(u32, u32)>)>,
    /// Buried clutter texels, ascending.
    buried: Vec<u32>,
}

/// Clutter texels: gather from blocks (C_b) and from other clutter, or (`clutter_gather:
/// exact`) a sparse row over the direct light of the texels hit. Consumes the rays (one per
/// clutter texel in global order), freeing each texel's once used.
fn clutter_texel_rows(
    inputs: &DrtInputs,
    rays: Vec<ClutterTexelRays>,
    rows: &SourceRows,
    burial: &Burial,
    stats: &mut DrtStats,
) -> ClutterRows {
    let (scene, g) = (inputs.scene, inputs.geometry);
    let n_blocks = scene.blocks.len();
    let inv = 1.0 / scene.settings.rays_per_texel as f64;
    let exact = scene.settings.clutter_gather == ClutterGather::Exact;
    let clutter_texels: Vec<usize> = g.clutter_texels.iter().flat_map(|r| r.clone()).collect();
    let mut out = ClutterRows {
        per_clutter: BTreeMap::new(),
        gathered: Vec::new(),
        buried: Vec::new(),
    };
    for (&x, r) in clutter_texels.iter().zip(rays) {
        let (hits, back) = (r.hits, r.back);
        let (owner, _) = rows.owners.local(x as u32);
        let texel = &g.texels[x];
        if burial.clutter_texel_buried(texel.position, texel.normal, owner - n_blocks, back) {
            // No light reaches it: no rows (its rays started inside what covers it).
            stats.buried_clutter_texels += 1;
            out.buried.push(x as u32);
            continue;
        }
        if exact {
            // Sparse row over the direct light of the texels hit (hit counts, made weights
            // when the gather is assembled).
            if !hits.is_empty() {
                out.gathered.push((x as u32, hits));
            }
            continue;
        }
        for (t, count) in hits {
            let weight = count as f64 * inv;
            let (source, l) = rows.owners.local(t);
            if source < n_blocks {
                add_row(
                    &mut out.per_clutter,
                    LitSource::Block(source as u32),
                    x as u32,
                    rows.l_imp[source].row(l),
                    weight,
                );
            } else if let Some(i) = rows.projection_of[source - n_blocks] {
                add_row(
                    &mut out.per_clutter,
                    LitSource::Clutter(i as u32),
                    x as u32,
                    rows.basis[i].row(l),
                    weight,
                );
            }
        }
    }
    out
}

/// Packs the rows into blocks: one entry per (target object, source), targets in block order
/// then the clutter, sources in [`LitSource`] order. Each target is packed on a worker (as its
/// rows were built on one: a worker's freed rows make room for the matrices it packs), taken in
/// order.
fn pack_entries(per_target: Vec<RowsBySource>, per_clutter: RowsBySource) -> Vec<DeltaBlock> {
    let targets: Vec<RowsBySource> = per_target
        .into_iter()
        .chain(std::iter::once(per_clutter))
        .collect();
    let packed: Vec<Vec<DeltaBlock>> = targets
        .into_par_iter()
        .map(|map| {
            map.into_iter()
                .map(|(key, rows)| {
                    let width = rows.values().next().map_or(0, |v| v.len());
                    let values: Vec<&Vec<f64>> = rows.values().collect();
                    let matrix = Mat::from_fn(rows.len(), width, |i, j| values[i][j]);
                    DeltaBlock {
                        rows: rows.keys().copied().collect(),
                        source: key.into(),
                        matrix,
                    }
                })
                .collect()
        })
        .collect();
    packed.into_iter().flatten().collect()
}

#[cfg(test)]
mod tests {
    use super::Burial;
    use lightfarm_proto::scene::Scene;

    /// Two rooms joined at x = 4; a crate standing in the doorway, a box pressed against its
    /// +z face.
    fn scene() -> Scene {
        Scene::from_json(
            r#"{ "format": "lightfarm.scene/1", "name": "doorway",
                 "blocks": [
                   { "id": "a", "min": [0,0,0], "max": [4,3,4], "open": ["+x"], "albedo": [0.5,0.5,0.5] },
                   { "id": "b", "min": [4,0,0], "max": [8,3,4], "open": ["-x"], "albedo": [0.5,0.5,0.5] } ],
                 "clutter": [
                   { "id": "crate", "box": { "min": [3.5,0,1], "max": [4.5,1,2] }, "albedo": [0.5,0.5,0.5] },
                   { "id": "pressed", "box": { "min": [3.6,0,2], "max": [4.4,0.8,2.5] }, "albedo": [0.5,0.5,0.5] } ] }"#,
        )
        .unwrap()
    }

    #[test]
    fn a_clutter_texel_is_buried_only_where_no_light_reaches_it() {
        let scene = scene();
        let burial = Burial {
            scene: &scene,
            e: 1e-6 * 8.0,
        };
        let buried =
            |p: [f64; 3], n: [f64; 3], own: usize| burial.clutter_texel_buried(p, n, own, 0.0);
        // The crate's top on the opening's plane: inside the level (a prop in a doorway).
        assert!(!buried([4.0, 1.0, 1.5], [0.0, 1.0, 0.0], 0));
        // Its +x face in room b, and its top in room a: exposed.
        assert!(!buried([4.5, 0.5, 1.5], [1.0, 0.0, 0.0], 0));
        assert!(!buried([3.75, 1.0, 1.25], [0.0, 1.0, 0.0], 0));
        // Its bottom on the floor: outside the level just below it.
        assert!(buried([3.75, 0.0, 1.25], [0.0, -1.0, 0.0], 0));
        // Its +z face where the other box presses against it, and that box's −z face.
        assert!(buried([4.0, 0.4, 2.0], [0.0, 0.0, 1.0], 0));
        assert!(buried([3.9, 0.4, 2.0], [0.0, 0.0, -1.0], 1));
        // The same +z face above the other box (y > 0.8) is exposed.
        assert!(!buried([4.0, 0.9, 2.0], [0.0, 0.0, 1.0], 0));
        // Outside every block, and rays that mostly hit back faces.
        assert!(buried([9.0, 0.5, 1.5], [1.0, 0.0, 0.0], 0));
        assert!(burial.clutter_texel_buried([4.5, 0.5, 1.5], [1.0, 0.0, 0.0], 0, 0.75));
    }
}
