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
//!   neighbours' shadowed transport minus their own unshadowed transport; with no valid
//!   neighbour on the face they get exactly minus their MRT transport (they are dark, never NaN).
//!
//! Clutter texels are a box's six faces or a mesh's lightmap atlas (`mesh_atlas`); every
//! operator here reads them by global texel index, so both kinds go through the same code. A
//! clutter object's basis is placed around its box, or around a mesh's bounding box.
//!
//! Model only what the scene needs: a block texel whose rays hit clutter less often than the
//! tolerance gets no row (counted in the report). All operators are albedo-free.
//!
//! Invariant: deterministic per texel stream; rows are global texel indices, ascending.

use std::collections::BTreeMap;

use faer::Mat;

use lightfarm_proto::bundle::{DeltaSource, TexelGather};
use lightfarm_proto::scene::{Aabb, ClutterBasis, ClutterGather, Opening, Scene, SceneGather};

use crate::bake::drt::clutter_basis::{clutter_basis, prior_lights, ClutterBasisOps};
use crate::bake::drt::error::DrtError;
use crate::bake::drt::lit_source::LitSource;
use crate::bake::drt::rays::{clutter_basis_unit, trace_all, DrtRayCache, RayPass};
use crate::bake::mrt::shape::ShapeOperators;
use crate::bake::scene::geometry::Geometry;
use crate::bake::tracer::Tracer;
use crate::bake::transport::build::MrtTransport;

/// Rows of one target, keyed by (source kind, source index) then global texel row.
type RowsBySource = BTreeMap<LitSource, BTreeMap<u32, Vec<f64>>>;

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

/// Accumulates `weight · row` into `map[source][global_row]`.
fn add_row(
    map: &mut BTreeMap<LitSource, BTreeMap<u32, Vec<f64>>>,
    source: LitSource,
    row: u32,
    values: &[f64],
    weight: f64,
) {
    let acc = map
        .entry(source)
        .or_default()
        .entry(row)
        .or_insert_with(|| vec![0.0; values.len()]);
    for (a, v) in acc.iter_mut().zip(values) {
        *a += weight * v;
    }
}

/// A matrix copied row-major, so a row is a contiguous slice.
struct RowMajor {
    cols: usize,
    data: Vec<f64>,
}

impl RowMajor {
    fn of(m: &Mat<f64>) -> RowMajor {
        let mut data = Vec::with_capacity(m.nrows() * m.ncols());
        for i in 0..m.nrows() {
            data.extend((0..m.ncols()).map(|j| m[(i, j)]));
        }
        RowMajor {
            cols: m.ncols(),
            data,
        }
    }

    fn row(&self, i: usize) -> &[f64] {
        &self.data[i * self.cols..(i + 1) * self.cols]
    }
}

/// Builds the DRT operators. `g` is the full geometry (blocks first, then clutter), `gb` the
/// blocks-only geometry with the same block texel indices.
#[allow(clippy::too_many_arguments)]
pub fn build_drt(
    scene: &Scene,
    openings: &[[Option<Opening>; 6]],
    g: &Geometry,
    gb: &Geometry,
    shapes: &[&ShapeOperators],
    mrt: &MrtTransport,
    cache: Option<&DrtRayCache>,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<DrtOperators, DrtError> {
    let settings = &scene.settings;
    let tracer = Tracer::new(g.primitives.clone(), g.scale());
    let block_tracer = Tracer::new(gb.primitives.clone(), gb.scale());
    let inv = 1.0 / settings.rays_per_texel as f64;
    let n_blocks = scene.blocks.len();
    let block_of: Vec<u32> = {
        let mut o = vec![u32::MAX; g.texels.len()];
        for (b, r) in g.block_texels.iter().enumerate() {
            for t in r.clone() {
                o[t] = b as u32;
            }
        }
        for (c, r) in g.clutter_texels.iter().enumerate() {
            for t in r.clone() {
                o[t] = (n_blocks + c) as u32;
            }
        }
        o
    };
    let local = |t: u32| -> (usize, usize) {
        let owner = block_of[t as usize] as usize;
        if owner < n_blocks {
            (owner, t as usize - g.block_texels[owner].start)
        } else {
            (owner, t as usize - g.clutter_texels[owner - n_blocks].start)
        }
    };

    // Clutter bases.
    let mut clutter = Vec::new();
    let mut stats = DrtStats::default();
    for (c, object) in scene.clutter.iter().enumerate() {
        let range = g.clutter_texels[c].clone();
        if range.is_empty() {
            continue;
        }
        // The box, or the mesh's bounds (where prior lights are placed around it).
        let bounds = g.clutter_shapes[c].bounds;
        let aabb = object.box_.unwrap_or(Aabb {
            min: bounds[0],
            max: bounds[1],
        });
        let basis = if settings.clutter_basis == ClutterBasis::Prior {
            let lights = prior_lights(scene, openings, c, &aabb);
            clutter_basis_unit(scene, g, c, &lights, cache, || {
                clutter_basis(scene, openings, g, &tracer, c, &aabb, range.clone())
            })?
        } else {
            clutter_basis(scene, openings, g, &tracer, c, &aabb, range.clone())?
        };
        stats.clutter_ranks.push(basis.basis.ncols());
        clutter.push((
            c,
            ClutterProjection {
                id: object.id.clone(),
                texel_offset: range.start,
                basis,
            },
        ));
    }
    // Scene clutter index → index in the bundle's clutter list (objects with texels).
    let projection_of: Vec<Option<usize>> = (0..scene.clutter.len())
        .map(|c| clutter.iter().position(|(k, _)| *k == c))
        .collect();

    // Buried texels: inside a clutter box (closed), or clutter texels outside every block.
    // `scale()` passes over every primitive: computed once, not per texel and object (which
    // made this test quadratic in the level's size).
    let e = 1e-6 * g.scale();
    let inside_box = |p: [f64; 3], skip: Option<usize>| {
        scene.clutter.iter().enumerate().any(|(c, object)| {
            if Some(c) == skip {
                return false;
            }
            let Some(b) = object.box_ else { return false };
            (0..3).all(|k| p[k] >= b.min[k] - e && p[k] <= b.max[k] + e)
        })
    };
    let inside_blocks = |p: [f64; 3]| {
        scene
            .blocks
            .iter()
            .any(|b| (0..3).all(|k| p[k] > b.min[k] + e && p[k] < b.max[k] - e))
    };

    // Both ray passes (block texels guided toward clutter; clutter texels), reusing what an
    // earlier bake traced where nothing it saw has changed.
    let pass = RayPass::new(scene, openings, g, gb, &tracer, &block_tracer);
    let rays = trace_all(&pass, cache, progress)?;
    stats.traced_texels = rays.traced_texels;
    stats.reused_texels = rays.reused_texels;
    let block_texels: Vec<usize> = (0..gb.texels.len()).collect();

    // Row-major copies of every block's L_imp and every clutter basis (rows are read per hit).
    let mut by_shape: Vec<(*const ShapeOperators, std::sync::Arc<RowMajor>)> = Vec::new();
    let l_imp_rows: Vec<std::sync::Arc<RowMajor>> = shapes
        .iter()
        .map(|s| {
            let ptr = *s as *const ShapeOperators;
            match by_shape.iter().find(|(p, _)| *p == ptr) {
                Some((_, rows)) => rows.clone(),
                None => {
                    let rows = std::sync::Arc::new(RowMajor::of(&s.l_imp));
                    by_shape.push((ptr, rows.clone()));
                    rows
                }
            }
        })
        .collect();
    let basis_rows: Vec<RowMajor> = clutter
        .iter()
        .map(|(_, p)| RowMajor::of(&p.basis.basis))
        .collect();

    // Accumulate per target block: map[(kind, source)][row] = values.
    let mut per_target: Vec<RowsBySource> = (0..n_blocks).map(|_| BTreeMap::new()).collect();
    let mut buried_scene: Vec<bool> = vec![false; g.texels.len()];
    // `scene_gather: exact`: block texel → the lit texels its cosine rays hit (rays each).
    let exact_scene = settings.scene_gather == SceneGather::Exact;
    let mut scene_rows: BTreeMap<u32, Vec<(u32, u32)>> = BTreeMap::new();
    for (&x, r) in block_texels.iter().zip(&rays.block) {
        let (occluded, reflected) = (&r.occluded, &r.reflected);
        let (target, _) = local(x as u32);
        let buried = inside_box(g.texels[x].position, None) || r.back_hits > 0.5;
        buried_scene[x] = buried;
        if buried {
            stats.buried_scene_texels += 1;
            continue;
        }
        if !r.sees_clutter(settings.tolerance) {
            stats.scene_texels_skipped += 1;
            continue;
        }
        stats.scene_texels_with_rows += 1;
        if exact_scene {
            // The gather replaces MRT and the deltas on this texel.
            scene_rows.insert(x as u32, r.hits.clone());
            continue;
        }
        for &(t, w) in occluded {
            let (source, l) = local(t);
            // Antiradiance: −L_imp at the wall behind.
            add_row(
                &mut per_target[target],
                LitSource::Block(source as u32),
                x as u32,
                l_imp_rows[source].row(l),
                -w,
            );
        }
        for &(k, w) in reflected {
            let (owner, l) = local(k);
            let c = owner - n_blocks;
            if let Some(i) = projection_of[c] {
                add_row(
                    &mut per_target[target],
                    LitSource::Clutter(i as u32),
                    x as u32,
                    basis_rows[i].row(l),
                    w,
                );
            }
        }
    }

    // Inpainting (§5) of buried block texels, face by face.
    for (target, map) in per_target.iter_mut().enumerate() {
        let range = g.block_texels[target].clone();
        // Every source whose MRT transport reaches the target, not only those with delta rows:
        // a buried texel must cancel light arriving from neighbouring blocks too (a room
        // wholly inside a clutter box still receives MRT light through its openings).
        let mut sources: Vec<LitSource> = map.keys().copied().collect();
        for b in 0..n_blocks {
            let key = LitSource::Block(b as u32);
            let reaches = b == target || mrt.row(shapes, target, b, 0).is_some();
            if reaches && !sources.contains(&key) {
                sources.push(key);
            }
        }
        for s in g
            .surfaces
            .iter()
            .filter(|s| s.texel_offset >= range.start && s.texel_offset < range.end)
        {
            let t = s.t;
            for j in 0..t {
                for i in 0..t {
                    let x = s.texel_offset + j * t + i;
                    if !buried_scene[x] {
                        continue;
                    }
                    // Nearest ring of valid neighbours on the same face.
                    let mut neighbours = Vec::new();
                    for radius in 1..t.max(2) {
                        for dj in -(radius as i64)..=radius as i64 {
                            for di in -(radius as i64)..=radius as i64 {
                                if di.abs().max(dj.abs()) != radius as i64 {
                                    continue;
                                }
                                let (ni, nj) = (i as i64 + di, j as i64 + dj);
                                if ni < 0 || nj < 0 || ni >= t as i64 || nj >= t as i64 {
                                    continue;
                                }
                                let n = s.texel_offset + nj as usize * t + ni as usize;
                                if !buried_scene[n] {
                                    neighbours.push(n);
                                }
                            }
                        }
                        if !neighbours.is_empty() {
                            break;
                        }
                    }
                    if neighbours.is_empty() {
                        stats.inpainted_without_neighbours += 1;
                    }
                    // Next to gathered texels: copy the first one's gather (its light is
                    // the gather alone, so averaging MRT-based values would be brighter).
                    if let Some(row) = neighbours.iter().find_map(|n| scene_rows.get(&(*n as u32)))
                    {
                        let row = row.clone();
                        scene_rows.insert(x as u32, row);
                        continue;
                    }
                    let x_local = x - range.start;
                    for &key in &sources {
                        let width = match key {
                            LitSource::Block(b) => shapes[b as usize].rank(),
                            LitSource::Clutter(c) => clutter[c as usize].1.basis.basis.ncols(),
                        };
                        let unshadowed = |row: usize| -> Vec<f64> {
                            match key {
                                LitSource::Block(b) => mrt
                                    .row(shapes, target, b as usize, row)
                                    .unwrap_or_else(|| vec![0.0; width]),
                                LitSource::Clutter(_) => vec![0.0; width],
                            }
                        };
                        // ΔU[x] = mean_n (U[n] + ΔU[n]) − U[x]; no neighbours: −U[x].
                        let mut value = vec![0.0; width];
                        if !neighbours.is_empty() {
                            let w = 1.0 / neighbours.len() as f64;
                            for &n in &neighbours {
                                let u = unshadowed(n - range.start);
                                let delta = map.get(&key).and_then(|m| m.get(&(n as u32)));
                                for c in 0..width {
                                    value[c] += w * (u[c] + delta.map_or(0.0, |d| d[c]));
                                }
                            }
                        }
                        let own = unshadowed(x_local);
                        for c in 0..width {
                            value[c] -= own[c];
                        }
                        if value.iter().any(|v| *v != 0.0) {
                            add_row(map, key, x as u32, &value, 1.0);
                        }
                    }
                }
            }
        }
    }

    // Clutter texels: gather from blocks (C_b) and from other clutter.
    let clutter_texels: Vec<usize> = g.clutter_texels.iter().flat_map(|r| r.clone()).collect();
    let mut per_clutter: RowsBySource = BTreeMap::new();
    let mut buried = Vec::new();
    let exact = settings.clutter_gather == ClutterGather::Exact;
    let mut gather = TexelGather {
        row_start: vec![0],
        ..Default::default()
    };
    // Block texel rows first (they precede clutter texels, so rows stay ascending).
    stats.scene_texels_gathered = scene_rows.len();
    for (&x, hits) in &scene_rows {
        gather.rows.push(x);
        for &(t, n) in hits {
            gather.cols.push(t);
            gather.values.push((n as f64 * inv) as f32);
        }
        gather.row_start.push(gather.cols.len() as u32);
    }
    let replaced: Vec<u32> = scene_rows.keys().copied().collect();
    for (&x, r) in clutter_texels.iter().zip(&rays.clutter) {
        let (hits, back) = (&r.hits, &r.back);
        let (owner, _) = local(x as u32);
        let p = g.texels[x].position;
        if !inside_blocks(p) || inside_box(p, Some(owner - n_blocks)) || *back > 0.5 {
            stats.buried_clutter_texels += 1;
            buried.push(x as u32);
        }
        if exact {
            // Sparse row over the direct light of the texels hit.
            let row: Vec<(u32, f32)> = hits
                .iter()
                .map(|&(t, n)| (t, (n as f64 * inv) as f32))
                .collect();
            if !row.is_empty() {
                gather.rows.push(x as u32);
                for (c, v) in row {
                    gather.cols.push(c);
                    gather.values.push(v);
                }
                gather.row_start.push(gather.cols.len() as u32);
            }
            continue;
        }
        for &(t, count) in hits {
            let weight = count as f64 * inv;
            let (source, l) = local(t);
            if source < n_blocks {
                add_row(
                    &mut per_clutter,
                    LitSource::Block(source as u32),
                    x as u32,
                    l_imp_rows[source].row(l),
                    weight,
                );
            } else if let Some(i) = projection_of[source - n_blocks] {
                add_row(
                    &mut per_clutter,
                    LitSource::Clutter(i as u32),
                    x as u32,
                    basis_rows[i].row(l),
                    weight,
                );
            }
        }
    }
    for (x, b) in buried_scene.iter().enumerate() {
        if *b {
            buried.push(x as u32);
        }
    }
    buried.sort_unstable();

    // Pack into blocks: one entry per (target object, source).
    let mut entries = Vec::new();
    for map in per_target.into_iter().chain(std::iter::once(per_clutter)) {
        for (key, rows) in map {
            let width = rows.values().next().map_or(0, |v| v.len());
            let values: Vec<&Vec<f64>> = rows.values().collect();
            let matrix = Mat::from_fn(rows.len(), width, |i, j| values[i][j]);
            entries.push(DeltaBlock {
                rows: rows.keys().copied().collect(),
                source: key.into(),
                matrix,
            });
        }
    }
    Ok(DrtOperators {
        direct_gather: (exact || exact_scene).then_some(gather),
        replaced,
        clutter: clutter.into_iter().map(|(_, p)| p).collect(),
        projection_of,
        entries,
        buried,
        stats,
    })
}
