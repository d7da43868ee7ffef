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
//! - **Traced**: `U_{B←A} = F_{BA} L_imp^A` (texels_B × r_A), rays from B's texels through the real
//!   (block) geometry hitting A's texels; pairs carrying less than `tolerance ·‖U_b^A‖_F²` are
//!   dropped.
//!
//! Invariant: clutter is ignored here (MRT transport is of the empty level); results are
//! independent of thread count.

use std::collections::{BTreeMap, VecDeque};

use faer::Mat;
use rayon::prelude::*;

use lightfarm_proto::scene::Opening;
use lightfarm_proto::Face;

use crate::bake::math::matrix::narrow;
use crate::bake::math::sampling::Purpose;
use crate::bake::mrt::one_bounce::gather_rows;
use crate::bake::mrt::shape::ShapeOperators;
use crate::bake::mrt::shape::Triplets;
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

fn energy(m: &Mat<f64>) -> f64 {
    let mut e = 0.0;
    for j in 0..m.ncols() {
        for i in 0..m.nrows() {
            e += m[(i, j)] * m[(i, j)];
        }
    }
    e
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

/// Traces cross-block operators through the blocks-only geometry `g` (whose block texel ranges
/// match `shapes`).
pub fn traced_transport(
    g: &Geometry,
    tracer: &Tracer,
    shapes: &[&ShapeOperators],
    rays: u32,
    seed: u64,
    tolerance: f64,
    progress: &(dyn Fn(u64) + Sync),
) -> (Vec<TracedBlock>, TransportStats) {
    let mut stats = TransportStats::default();
    let owner: Vec<usize> = {
        let mut o = vec![usize::MAX; g.texels.len()];
        for (b, range) in g.block_texels.iter().enumerate() {
            for t in range.clone() {
                o[t] = b;
            }
        }
        o
    };
    let mut out = Vec::new();
    for (target, range) in g.block_texels.iter().enumerate() {
        let texels: Vec<usize> = range.clone().collect();
        let rows = gather_rows(
            g,
            tracer,
            &texels,
            rays,
            seed,
            Purpose::TracedTransport,
            progress,
        );
        let mut per_source: BTreeMap<usize, Mat<f64>> = BTreeMap::new();
        for (x, row) in rows.iter().enumerate() {
            for &(t, w) in row {
                let source = owner[t as usize];
                if source == target || source == usize::MAX {
                    continue;
                }
                let l_imp = &shapes[source].l_imp;
                let local = t as usize - g.block_texels[source].start;
                let m = per_source
                    .entry(source)
                    .or_insert_with(|| Mat::zeros(texels.len(), l_imp.ncols()));
                for j in 0..l_imp.ncols() {
                    m[(x, j)] += w as f64 * l_imp[(local, j)];
                }
            }
        }
        for (source, matrix) in per_source {
            if energy(&matrix) >= tolerance * energy(&shapes[source].u_b) {
                stats.pairs_kept += 1;
                out.push(TracedBlock {
                    target_block: target,
                    source_block: source,
                    matrix,
                });
            } else {
                stats.pairs_dropped += 1;
            }
        }
    }
    (out, stats)
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
