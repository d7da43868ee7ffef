//! Inter-block transport (MRT §3.3 and the runtime of paper 001): how indirect light from a
//! lamp in one block reaches blocks one, two and more openings away.
//!
//! Two ways, chosen by `settings.transport`:
//! - **Lightfield** (scene-independent parts, composed at scene init): source block A's implicit
//!   lights leave through each opening as `OutImp_o` (LF × r_A); at the neighbour's coincident
//!   opening they are reduced by `W` to q coefficients (`T_prop` entry, q × r_A) and, through the
//!   neighbour's `Pass` operators, carried on to further openings. Propagation stops where the
//!   carried energy `‖X‖_F²` falls below `tolerance ·` the energy A sent out, not after a fixed
//!   number of hops.
//! - **Traced** (the default): `U_{B←A} = F_{BA} L_imp^A` (texels_B × r_A), rays from B's texels
//!   leaving B through its openings into the real (block) geometry and hitting A's texels; per
//!   target, the weakest sources are dropped while together they carry at most 1% of
//!   `tolerance` of what the target receives. Made target by target ([`TracedTransport`]), with
//!   the noise of its rays estimated for the compaction. Where light crosses an opening close to
//!   the texels it lights, the lightfield's `cells² × dirs²` bins blur it and the traced rays do
//!   not: on the maze at 16 texels per face DRT's all-bounce error is 0.0235 traced against
//!   0.0398 through lightfields (`tests/data/multibounce_accuracy.md`).
//!
//! Invariant: clutter is ignored here (MRT transport is of the empty level); results are
//! independent of thread count.

use std::collections::{BTreeMap, VecDeque};

use faer::Mat;
use rayon::prelude::*;

use lightfarm_proto::scene::{Aabb, Block, Opening, Transport};
use lightfarm_proto::Face;

use crate::bake::math::matrix::{energy, narrow};
use crate::bake::math::sampling::{
    sample_cosine_hemisphere, sobol_2d, stream_key, to_world, Purpose,
};
use crate::bake::mrt::shape::Triplets;
use crate::bake::mrt::shape::{box_exit, hit_texel, ShapeOperators};
use crate::bake::mrt::shape_symmetry::InstanceLightfield;
use crate::bake::scene::geometry::Geometry;
use crate::bake::tracer::Tracer;
use crate::bake::transport::source_bases::FactoringStats;

/// Per block, its openings as the propagation reads them: each face with its `Pass` operators
/// (incoming lightfield at a face → outgoing here), in the order the block's operators list
/// its openings (the queue's order, so the sums' order).
pub type BlockPasses<'a> = Vec<Vec<(Face, &'a [(Face, Triplets)])>>;

/// One `T_prop` block: reduced incoming lightfield at (target, face) from source's b.
#[derive(Clone)]
pub struct PropBlock {
    pub target_block: usize,
    pub target_face: Face,
    pub source_block: usize,
    /// q × r_source, summed in f64 and held in f32: a large level's `T_prop` is the bulk of
    /// its bake's memory while it is propagated (1,000 blocks: 1.6 GB in f64), and f32's
    /// rounding (6e-8 relative) is far below the compaction's truncation (`tolerance` of the
    /// energy) and the bundle's f16/8-bit codes.
    pub matrix: Mat<f32>,
}

/// One traced cross-block operator.
#[derive(Clone)]
pub struct TracedBlock {
    pub target_block: usize,
    pub source_block: usize,
    /// texels_target × r_source.
    pub matrix: Mat<f64>,
}

/// Counters for the bake report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TransportStats {
    /// Lightfield: propagation steps taken and cut by the energy criterion.
    pub steps: usize,
    pub cut: usize,
    pub max_hops: usize,
    /// Traced: pairs kept and dropped.
    pub pairs_kept: usize,
    pub pairs_dropped: usize,
    /// Compacted transport: rank k of each receiving block's operator.
    pub compact_ranks: Vec<usize>,
    /// Compacted transport: the sources' shared bases.
    pub factoring: FactoringStats,
}

/// Composes lightfield transport over the connectivity graph. Per block, `passes` gives its
/// openings (in its operators' order) with their `Pass` operators, and `lightfields` their
/// `OutImp` and `W`.
pub fn lightfield_transport(
    passes: &BlockPasses,
    lightfields: &[InstanceLightfield],
    openings: &[[Option<Opening>; 6]],
    tolerance: f64,
) -> (Vec<PropBlock>, TransportStats) {
    let hop_limit = 4 * passes.len() + 4;
    // Sources propagate independently and every entry's key holds its source, so the sources
    // run in parallel and their entries are merged without sums across sources: the same bits
    // at any thread count.
    let per_source: Vec<(BTreeMap<(usize, usize), Mat<f32>>, TransportStats)> = (0..passes.len())
        .into_par_iter()
        .map(|source| propagate_source(source, passes, lightfields, openings, tolerance, hop_limit))
        .collect();
    let mut stats = TransportStats::default();
    let mut acc: BTreeMap<(usize, usize, usize), Mat<f32>> = BTreeMap::new();
    for (source, (entries, source_stats)) in per_source.into_iter().enumerate() {
        stats.steps += source_stats.steps;
        stats.cut += source_stats.cut;
        stats.max_hops = stats.max_hops.max(source_stats.max_hops);
        for ((target, face), matrix) in entries {
            acc.insert((target, face, source), matrix);
        }
    }
    let blocks = acc
        .into_iter()
        .map(|((target, face, source), matrix)| PropBlock {
            target_block: target,
            target_face: Face::ALL[face],
            source_block: source,
            matrix,
        })
        .collect();
    (blocks, stats)
}

/// One source block's propagation: its implicit lights leave through each opening and are
/// carried on until the energy criterion cuts them. Entries keyed (target, face), summed in
/// queue order in f64, then rounded to f32 ([`PropBlock::matrix`]); `steps`, `cut` and
/// `max_hops` counted for this source alone.
fn propagate_source(
    source: usize,
    passes: &BlockPasses,
    lightfields: &[InstanceLightfield],
    openings: &[[Option<Opening>; 6]],
    tolerance: f64,
    hop_limit: usize,
) -> (BTreeMap<(usize, usize), Mat<f32>>, TransportStats) {
    let mut stats = TransportStats::default();
    let mut acc: BTreeMap<(usize, usize), Mat<f64>> = BTreeMap::new();
    let mut queue: VecDeque<(usize, Face, Mat<f64>, usize)> = VecDeque::new();
    let mut sent = 0.0;
    for &(out_face, _) in &passes[source] {
        if let Some(Opening::Neighbour { block, face }) = openings[source][out_face.index()] {
            let out_imp = lightfields[source]
                .out_imp(out_face)
                .expect("a block's lightfield has its openings");
            sent += energy(&out_imp);
            queue.push_back((block, face, out_imp, 1));
        }
    }
    while let Some((target, face, x, hops)) = queue.pop_front() {
        stats.steps += 1;
        stats.max_hops = stats.max_hops.max(hops);
        let Some(w) = lightfields[target].w(face) else {
            continue;
        };
        let reduced = w.as_ref() * &x;
        acc.entry((target, face.index()))
            .and_modify(|m| *m += &reduced)
            .or_insert(reduced);
        for &(next, pass_from) in &passes[target] {
            if next == face {
                continue;
            }
            let Some(Opening::Neighbour {
                block: next_block,
                face: next_face,
            }) = openings[target][next.index()]
            else {
                continue;
            };
            let Some((_, triplets)) = pass_from.iter().find(|(from, _)| *from == face) else {
                continue;
            };
            let lf = lightfields[target]
                .len(next)
                .expect("a block's lightfield has its openings");
            let mut carried = Mat::<f64>::zeros(lf, x.ncols());
            for &(row, col, v) in triplets {
                for j in 0..x.ncols() {
                    carried[(row as usize, j)] += v * x[(col as usize, j)];
                }
            }
            if energy(&carried) >= tolerance * sent && hops < hop_limit {
                queue.push_back((next_block, next_face, carried, hops + 1));
            } else {
                stats.cut += 1;
            }
        }
    }
    let acc = acc.into_iter().map(|(key, m)| (key, narrow(&m))).collect();
    (acc, stats)
}

/// The share of the tolerance the traced transport's truncation of weak sources may drop
/// ([`TracedTransport::into_target`]). The operators' energy weighs every source as if it were
/// lit alike, but a dim block's light often comes from one lit source among many dark ones, and
/// its light is all that block gets: at the whole tolerance (1e-3) the maze's DRT all-bounce
/// error was 0.0251, at a hundredth of it 0.0211, about what dropping nothing gives (0.0209),
/// for 1.3% fewer bytes than keeping everything (before the compaction to the noise).
const DROP_SHARE: f64 = 0.01;

/// The traced operators into one target block ([`TracedTransport::into_target`]).
pub struct TracedTarget {
    /// Ascending in source.
    pub blocks: Vec<TracedBlock>,
    /// Sources whose light the truncation dropped.
    pub dropped: usize,
    /// The sampling noise of `blocks`: `‖G_½ − G‖_F²`, with `G_½` the same operators from the
    /// first half of the rays. `G` is the mean of the two halves, so `G_½ − G` is half their
    /// difference, and for independent rays its expected energy is exactly `G`'s expected
    /// squared error. Sobol' rays converge faster than independent ones, so it errs high.
    pub noise: f64,
}

/// A block as the traced transport sees it from inside: its box and which faces are open.
#[derive(Clone, Copy, Debug)]
pub struct BlockBox {
    pub aabb: Aabb,
    /// By `Face::index`.
    pub open: [bool; 6],
}

impl BlockBox {
    /// The box of a scene's block.
    pub fn of(block: &Block) -> BlockBox {
        let mut open = [false; 6];
        for f in &block.open {
            open[f.index()] = true;
        }
        BlockBox {
            aabb: block.aabb(),
            open,
        }
    }
}

/// Traced inter-block transport, made one target block at a time
/// ([`TracedTransport::into_target`]) so a bake can compact and store each target's operators
/// and let them go before tracing the next: at 1,000 blocks the whole traced transport is
/// ~3 GB in f64.
///
/// Rays start at the target's texels (the cosine-weighted stream `Purpose::TracedTransport`,
/// the same rays whatever else changes) and only those leaving the target's box through an
/// open face are traced: a ray leaving through a closed face hits the block's own wall, whose
/// light `U_b` already carries. A hit on a texel of source block A adds A's implicit-light row
/// `L_imp^A[t]` to the target texel's row of `U_{B←A}`, weighted by 1/rays.
pub struct TracedTransport<'a> {
    g: &'a Geometry,
    tracer: &'a Tracer,
    boxes: &'a [BlockBox],
    shapes: &'a [&'a ShapeOperators],
    /// Block of each texel of `g` (`u32::MAX`: none).
    owner: Vec<u32>,
    rays: u32,
    seed: u64,
    tolerance: f64,
}

impl<'a> TracedTransport<'a> {
    /// Over the blocks-only geometry `g` (whose block texel ranges match `shapes` and `boxes`).
    pub fn new(
        g: &'a Geometry,
        tracer: &'a Tracer,
        boxes: &'a [BlockBox],
        shapes: &'a [&'a ShapeOperators],
        rays: u32,
        seed: u64,
        tolerance: f64,
    ) -> TracedTransport<'a> {
        let mut owner = vec![u32::MAX; g.texels.len()];
        for (b, range) in g.block_texels.iter().enumerate() {
            for t in range.clone() {
                owner[t] = b as u32;
            }
        }
        TracedTransport {
            g,
            tracer,
            boxes,
            shapes,
            owner,
            rays,
            seed,
            tolerance,
        }
    }

    /// How many blocks (targets) there are.
    pub fn blocks(&self) -> usize {
        self.g.block_texels.len()
    }

    /// The operators into `target`, ascending in source, how many sources were dropped and
    /// the sampling noise of what is kept.
    ///
    /// Truncation, relative to what the target receives (as every other truncation here is
    /// relative to the operator it truncates): the weakest sources go while together they carry
    /// at most `DROP_SHARE` of `tolerance` of the energy `Σ_A ‖U_{B←A}‖_F²`. The criterion
    /// before, relative to each source's own light (`‖U_b^A‖² · tolerance`), dropped blocks that
    /// are all a dim block receives: on the maze at 16 texels per face DRT's all-bounce error
    /// was 0.0361 with it against 0.0211.
    /// `progress` gets one per texel.
    pub fn into_target(&self, target: usize, progress: &(dyn Fn(u64) + Sync)) -> TracedTarget {
        let range = self.g.block_texels[target].clone();
        let block = self.boxes[target];
        let extent = block.aabb.extent();
        let sign = |s: u32| self.g.surfaces[s as usize].normal_sign;
        // Per texel, the source texels its rays hit, sorted (one entry per ray, tagged with
        // the half of the rays it is in).
        let hits: Vec<Vec<u64>> = range
            .clone()
            .into_par_iter()
            .map(|x| {
                let texel = &self.g.texels[x];
                let key = stream_key(self.seed, Purpose::TracedTransport, x as u64);
                let local = [
                    texel.position[0] - block.aabb.min[0],
                    texel.position[1] - block.aabb.min[1],
                    texel.position[2] - block.aabb.min[2],
                ];
                let mut out = Vec::new();
                for i in 0..self.rays {
                    let d = to_world(sample_cosine_hemisphere(sobol_2d(key, i)), texel.normal);
                    let (face, _) = box_exit(local, d, extent);
                    if !block.open[face.index()] {
                        continue;
                    }
                    let Some(hit) = self.tracer.closest(texel.position, d, f64::INFINITY, &sign)
                    else {
                        continue;
                    };
                    let Some(t) = hit_texel(self.g, self.tracer, &hit) else {
                        continue;
                    };
                    let source = self.owner[t];
                    if source != u32::MAX && source as usize != target {
                        // The texel, and whether the ray is of the second half.
                        out.push(((t as u64) << 1) | u64::from(2 * i >= self.rays));
                    }
                }
                out.sort_unstable();
                progress(1);
                out
            })
            .collect();
        let inv = 1.0 / self.rays as f64;
        let half = self.rays.div_ceil(2);
        // Per source, its texels the rays hit: (target texel, source texel, weight, weight
        // over the first half of the rays), target texels ascending.
        let mut hit_lists: BTreeMap<usize, Vec<(u32, u32, f64, f64)>> = BTreeMap::new();
        for (x, row) in hits.iter().enumerate() {
            for run in row.chunk_by(|a, b| a >> 1 == b >> 1) {
                let t = (run[0] >> 1) as usize;
                let source = self.owner[t] as usize;
                let local = t - self.g.block_texels[source].start;
                let first = run.iter().filter(|h| *h & 1 == 0).count();
                hit_lists.entry(source).or_default().push((
                    x as u32,
                    local as u32,
                    run.len() as f64 * inv,
                    first as f64 / half as f64,
                ));
            }
        }
        // Per source: the operator `S L_imp^A` and its half-rays difference `(S_½ − S) L_imp^A`,
        // both from one dense product (`S`: the hits' weights, target texels × source texels).
        let per_source: BTreeMap<usize, (Mat<f64>, Mat<f64>)> = hit_lists
            .into_par_iter()
            .map(|(source, list)| {
                let l_imp = &self.shapes[source].l_imp;
                let n = range.len();
                let mut s = Mat::<f64>::zeros(2 * n, l_imp.nrows());
                for &(x, t, w, w_first) in &list {
                    s[(x as usize, t as usize)] = w;
                    s[(n + x as usize, t as usize)] = w_first - w;
                }
                let both = &s * l_imp;
                (
                    source,
                    (both.subrows(0, n).to_owned(), both.subrows(n, n).to_owned()),
                )
            })
            .collect();
        let mut weakest: Vec<(f64, usize)> = per_source
            .iter()
            .map(|(source, (m, _))| (energy(m), *source))
            .collect();
        let total: f64 = weakest.iter().map(|(e, _)| e).sum();
        weakest.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut dropped_energy = 0.0;
        let mut dropped = std::collections::BTreeSet::new();
        for (e, source) in weakest {
            if dropped_energy + e > DROP_SHARE * self.tolerance * total {
                break;
            }
            dropped_energy += e;
            dropped.insert(source);
        }
        let mut noise = 0.0;
        let blocks = per_source
            .into_iter()
            .filter(|(source, _)| !dropped.contains(source))
            .map(|(source, (matrix, difference))| {
                noise += energy(&difference);
                TracedBlock {
                    target_block: target,
                    source_block: source,
                    matrix,
                }
            })
            .collect();
        TracedTarget {
            blocks,
            dropped: dropped.len(),
            noise,
        }
    }
}

/// The MRT inter-block operators of a bake, kept in f64 for DRT's inpainting.
pub enum MrtTransport {
    Lightfield(Vec<PropBlock>),
    Traced(Vec<TracedBlock>),
}

impl MrtTransport {
    /// The operators into the target blocks `keep` marks (indexed by block; a block past its
    /// end is not marked), in transport order.
    pub fn for_targets(&self, keep: &[bool]) -> MrtTransport {
        fn pick<T: Clone>(blocks: &[T], keep: impl Fn(&T) -> bool) -> Vec<T> {
            blocks.iter().filter(|b| keep(b)).cloned().collect()
        }
        let marked = |b: usize| keep.get(b).copied().unwrap_or(false);
        match self {
            MrtTransport::Lightfield(blocks) => {
                MrtTransport::Lightfield(pick(blocks, |b| marked(b.target_block)))
            }
            MrtTransport::Traced(blocks) => {
                MrtTransport::Traced(pick(blocks, |b| marked(b.target_block)))
            }
        }
    }

    /// Keeps only the operators into target blocks `keep` marks (what a later reader needs),
    /// in place: the others are dropped without copying the kept ones, so the bake's peak is
    /// not the transport plus a copy of what it keeps.
    pub fn retain_targets(&mut self, keep: &[bool]) {
        let marked = |b: usize| keep.get(b).copied().unwrap_or(false);
        match self {
            MrtTransport::Lightfield(blocks) => blocks.retain(|b| marked(b.target_block)),
            MrtTransport::Traced(blocks) => blocks.retain(|b| marked(b.target_block)),
        }
    }

    /// The parts of one transport of `kind` (each the operators into one target, targets
    /// ascending) back to back: the whole transport, in transport order.
    pub fn concat(kind: Transport, parts: impl Iterator<Item = MrtTransport>) -> MrtTransport {
        let mut lightfield = Vec::new();
        let mut traced = Vec::new();
        for part in parts {
            match part {
                MrtTransport::Lightfield(blocks) => lightfield.extend(blocks),
                MrtTransport::Traced(blocks) => traced.extend(blocks),
            }
        }
        match kind {
            Transport::Lightfield => MrtTransport::Lightfield(lightfield),
            Transport::Traced => MrtTransport::Traced(traced),
        }
    }

    /// The operators split by target block, ascending, each part in transport order (moved,
    /// not copied).
    pub fn split_by_target(self) -> Vec<(usize, MrtTransport)> {
        fn split<T>(blocks: Vec<T>, target: impl Fn(&T) -> usize) -> BTreeMap<usize, Vec<T>> {
            let mut parts: BTreeMap<usize, Vec<T>> = BTreeMap::new();
            for b in blocks {
                parts.entry(target(&b)).or_default().push(b);
            }
            parts
        }
        match self {
            MrtTransport::Lightfield(blocks) => split(blocks, |b| b.target_block)
                .into_iter()
                .map(|(t, part)| (t, MrtTransport::Lightfield(part)))
                .collect(),
            MrtTransport::Traced(blocks) => split(blocks, |b| b.target_block)
                .into_iter()
                .map(|(t, part)| (t, MrtTransport::Traced(part)))
                .collect(),
        }
    }

    /// Whether source block `source`'s light reaches target block `target` (its own block, or
    /// through an inter-block term): exactly when [`MrtTransport::row`] is `Some`, without
    /// computing a row.
    pub fn reaches(&self, shapes: &[&ShapeOperators], target: usize, source: usize) -> bool {
        target == source
            || match self {
                MrtTransport::Traced(blocks) => blocks
                    .iter()
                    .any(|b| b.target_block == target && b.source_block == source),
                MrtTransport::Lightfield(blocks) => blocks.iter().any(|b| {
                    b.target_block == target
                        && b.source_block == source
                        && shapes[target].opening(b.target_face).is_some()
                }),
            }
    }

    /// Row `local` of the operator mapping source block `source`'s `b` to indirect light on
    /// target block `target`'s texels (albedo-free): `U_b` for the block itself plus the
    /// inter-block term. None when the source does not reach the target.
    pub fn row(
        &self,
        shapes: &[&ShapeOperators],
        target: usize,
        source: usize,
        local: usize,
    ) -> Option<Vec<f64>> {
        let r = shapes[source].rank();
        let mut row = vec![0.0; r];
        let mut any = false;
        if target == source {
            let u_b = &shapes[target].u_b;
            for (j, x) in row.iter_mut().enumerate() {
                *x += u_b[(local, j)];
            }
            any = true;
        }
        match self {
            MrtTransport::Traced(blocks) => {
                for b in blocks
                    .iter()
                    .filter(|b| b.target_block == target && b.source_block == source)
                {
                    for (j, x) in row.iter_mut().enumerate() {
                        *x += b.matrix[(local, j)];
                    }
                    any = true;
                }
            }
            MrtTransport::Lightfield(blocks) => {
                for b in blocks
                    .iter()
                    .filter(|b| b.target_block == target && b.source_block == source)
                {
                    let Some(opening) = shapes[target].opening(b.target_face) else {
                        continue;
                    };
                    for k in 0..opening.u_r.ncols() {
                        let u = opening.u_r[(local, k)];
                        for (j, x) in row.iter_mut().enumerate() {
                            *x += u * f64::from(b.matrix[(k, j)]);
                        }
                    }
                    any = true;
                }
            }
        }
        any.then_some(row)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::mrt::one_bounce::gather_rows;
    use crate::bake::mrt::shape::ShapeStats;

    /// Three unit boxes in a row along x, open where they meet (light flies straight through
    /// the middle one), 4 texels per face; per block a made-up `L_imp` of rank 3.
    fn row_of_boxes() -> (Geometry, Vec<BlockBox>, Vec<ShapeOperators>) {
        let opens: [&[Face]; 3] = [&[Face::PosX], &[Face::NegX, Face::PosX], &[Face::NegX]];
        let mut g = Geometry::default();
        let mut boxes = Vec::new();
        for (b, open) in opens.iter().enumerate() {
            let aabb = Aabb {
                min: [b as f64, 0.0, 0.0],
                max: [b as f64 + 1.0, 1.0, 1.0],
            };
            let closed: Vec<Face> = Face::ALL
                .into_iter()
                .filter(|f| !open.contains(f))
                .collect();
            let range = g.add_block(b, "b", &aabb, &closed, |_| [0.5; 3], 4);
            g.block_texels.push(range);
            let mut mask = [false; 6];
            for f in *open {
                mask[f.index()] = true;
            }
            boxes.push(BlockBox { aabb, open: mask });
        }
        let shapes = g
            .block_texels
            .iter()
            .enumerate()
            .map(|(b, range)| ShapeOperators {
                key: format!("b{b}"),
                u_b: Mat::zeros(range.len(), 3),
                t_db: Mat::zeros(0, 0),
                l_imp: Mat::from_fn(range.len(), 3, |i, j| {
                    1.0 + ((7 * i + 3 * j + b) % 11) as f64 / 5.0
                }),
                openings: Vec::new(),
                stats: ShapeStats::default(),
            })
            .collect();
        (g, boxes, shapes)
    }

    fn traced_into(
        g: &Geometry,
        boxes: &[BlockBox],
        shapes: &[ShapeOperators],
        target: usize,
        rays: u32,
        tolerance: f64,
    ) -> TracedTarget {
        let tracer = Tracer::new(g.primitives.clone(), 3.0);
        let refs: Vec<&ShapeOperators> = shapes.iter().collect();
        TracedTransport::new(g, &tracer, boxes, &refs, rays, 5, tolerance)
            .into_target(target, &|_| {})
    }

    /// Skipping the rays that leave through a closed face changes no operator: the same as
    /// tracing every ray of the stream (`gather_rows`) and keeping the hits on other blocks.
    #[test]
    fn skipping_rays_that_stay_in_their_block_changes_no_operator() {
        let (g, boxes, shapes) = row_of_boxes();
        let tracer = Tracer::new(g.primitives.clone(), 3.0);
        for target in 0..3 {
            let got = traced_into(&g, &boxes, &shapes, target, 512, 0.0);
            let texels: Vec<usize> = g.block_texels[target].clone().collect();
            let rows = gather_rows(
                &g,
                &tracer,
                &texels,
                512,
                5,
                Purpose::TracedTransport,
                &|_| {},
            );
            let mut want: BTreeMap<usize, Mat<f64>> = BTreeMap::new();
            for (x, row) in rows.iter().enumerate() {
                for &(t, w) in row {
                    let t = t as usize;
                    let source = (0..3).find(|&b| g.block_texels[b].contains(&t)).unwrap();
                    if source == target {
                        continue;
                    }
                    let local = t - g.block_texels[source].start;
                    let m = want
                        .entry(source)
                        .or_insert_with(|| Mat::zeros(texels.len(), 3));
                    for j in 0..3 {
                        m[(x, j)] += f64::from(w) * shapes[source].l_imp[(local, j)];
                    }
                }
            }
            let sources: Vec<usize> = got.blocks.iter().map(|b| b.source_block).collect();
            assert_eq!(
                sources,
                want.keys().copied().collect::<Vec<_>>(),
                "target {target}"
            );
            // The end boxes see each other through the middle one's two openings.
            assert_eq!(sources.len(), 2, "target {target}");
            for b in &got.blocks {
                let w = &want[&b.source_block];
                let error = energy(&(&b.matrix - w)).sqrt() / energy(w).sqrt();
                assert!(
                    error < 1e-6,
                    "target {target} source {}: {error}",
                    b.source_block
                );
            }
            assert_eq!(got.dropped, 0);
        }
    }

    /// The weakest sources go while together they carry at most `DROP_SHARE · tolerance` of
    /// what the target receives, and never a stronger one before a weaker.
    #[test]
    fn dropped_sources_carry_at_most_their_share_of_the_tolerance() {
        let (g, boxes, shapes) = row_of_boxes();
        let all = traced_into(&g, &boxes, &shapes, 0, 256, 0.0);
        let energies: Vec<f64> = all.blocks.iter().map(|b| energy(&b.matrix)).collect();
        let total: f64 = energies.iter().sum();
        let (weak, strong) = (energies[1], energies[0]);
        assert!(weak < strong, "the far box sends less: {energies:?}");
        // Just enough tolerance to drop the far box, then just too little.
        let enough = weak / total / DROP_SHARE;
        let cut = traced_into(&g, &boxes, &shapes, 0, 256, enough * 1.001);
        assert_eq!((cut.dropped, cut.blocks.len()), (1, 1));
        assert_eq!(cut.blocks[0].source_block, 1);
        let kept = traced_into(&g, &boxes, &shapes, 0, 256, enough * 0.999);
        assert_eq!((kept.dropped, kept.blocks.len()), (0, 2));
        assert!(cut.noise < kept.noise, "the noise is of what is kept");
    }

    /// The noise estimate falls as the rays grow and is no smaller than the error it
    /// estimates, measured against the same operators from 16,384 rays (16–256 times as many).
    #[test]
    fn noise_estimate_falls_with_the_rays_and_covers_the_error() {
        let (g, boxes, shapes) = row_of_boxes();
        let exact = traced_into(&g, &boxes, &shapes, 0, 16384, 0.0);
        let mut last = f64::INFINITY;
        for rays in [64, 256, 1024] {
            let got = traced_into(&g, &boxes, &shapes, 0, rays, 0.0);
            let error: f64 = got
                .blocks
                .iter()
                .zip(&exact.blocks)
                .map(|(a, b)| energy(&(&a.matrix - &b.matrix)))
                .sum();
            assert!(got.noise > 0.0 && got.noise.is_finite());
            assert!(
                error <= got.noise,
                "{rays} rays: error {error:e} > noise {:e}",
                got.noise
            );
            assert!(
                got.noise < last / 2.0,
                "{rays} rays: {:e} after {last:e}",
                got.noise
            );
            last = got.noise;
        }
    }
}
