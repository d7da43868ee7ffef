//! [`Bounces::Converged`](super::Bounces::Converged) for [`Method::Drt`](super::Method::Drt) in
//! the blocks' and clutter objects' coefficient space: the bounces after the first never go
//! back to texels (module `reduced` does the same for MRT, without clutter).
//!
//! DRT's one-bounce operator is `A x = D (y(z(x)) + G x)`: `z(x)` projects the light `x` on
//! every block (`b = T_d→b x`) and clutter object (`c = t_dc x`), `y(z)` is the albedo-free
//! light the operators make from those coefficients (`U_b b`, the transport, every delta
//! entry), `G` the exact clutter gather (rows on clutter texels, reading texels of blocks and
//! clutter) and `D` the albedo. All bounces `I` solve `I = A (L_d + I)`. With `w = z(L_d + I)`,
//! the coefficients of all the light leaving texels, that is a system over coefficients alone,
//! `w = z₀ + f + M w`:
//! - a block's rows: `b = b₀ + T_d→b D y(w)` (a block texel's bounced light is `D y(w)`);
//! - a clutter object's: `c = c₀ + t_dc D (y(w) + G L_d + G_blocks D y(w) + G_clutter I)`.
//!   The gather's reads of clutter texels take their bounced light as the clutter basis's
//!   implied light `B (c − c₀)` (`B = t_dcᵀ`, orthonormal columns): exact for light in the
//!   basis's span, and used only for light that bounced off one clutter object onto another;
//!   for a gather that reads no clutter texel the system is exact.
//!
//! `M`'s pieces are the products `P diag(ρ) X` of a projector `P` with every producer `X` of
//! light on the texels `P` reads, made once (on the first such solve):
//! - projectors: a block's `T_d→b`, a clutter object's `t_dc` and the gather seen from a
//!   clutter object's coefficients, `ρ_j t_dc G`, dense over the texels it reads (its block
//!   texels read the operators' light, its clutter texels the implied light);
//! - producers: `U_b`, a transport entry's `Y` (traced: its matrix), a delta entry's matrix, a
//!   clutter object's implied light `B`.
//!
//! A compact transport entry's `Z` and a low-rank delta's `mix` stay shared: each application
//! computes them once ("mids"), then every piece reading them does. After the solve `I` is made
//! once on texels: DRT steps 1–3 with `w`'s coefficients, plus the gather of the light leaving
//! every texel (`L_d + I`, the implied light on clutter texels), times the albedo. GMRES runs
//! on the coefficients weighted as in `reduced` (a block's by its `U_b` column norms; a clutter
//! object's by 1, its basis being orthonormal).
//!
//! Falls back to the texel path (None) for what it does not model: a lightfield transport, a
//! delta entry over direct light (`DeltaSource::Direct`), replaced texels, a gather row outside
//! the clutter or a read outside every block and clutter object, a gathering clutter object of
//! more than one albedo.
//!
//! Units: coefficients as in `mrt` and `drt`; pieces map coefficients of light leaving texels
//! to the next bounce's coefficients.
//!
//! Invariants: pieces are made from the runtime's (symmetry-unfolded) bundle in a fixed order
//! and summed per albedo group in row order, and applied in that order on the calling thread:
//! results are deterministic and bit-identical at any thread count. Nothing allocates after
//! the first solve.

use lightfarm_proto::bundle::{Bundle, DeltaSource, Matrix, TexelGather, TransportOps};

use super::drt::Deltas;
use super::kernels::{group, planar, set_matvec, stack_sources};
use super::krylov::Krylov;
use super::packed_ops::{BlockSlots, PackedOps};
use super::reduced::{block_weights, Piece};
use crate::packed::PackedMatrix;

/// What a piece multiplies: a block's or clutter object's coefficients, or a mid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Input {
    Block(usize),
    Clutter(usize),
    Mid(usize),
}

/// A product shared by several pieces, made once per application.
#[derive(Clone, Copy, Debug)]
enum MidOp {
    /// `Z · [b_s]` of compact transport entry i.
    Compact(usize),
    /// `mix · x_source` of low-rank delta entry i.
    Mix(usize),
    /// `matrix · x_source` of delta entry i without `mix` and with fewer rows than columns:
    /// its pieces then read its rows' light (r × rows) instead of its source (r × cols).
    Rows(usize),
}

#[derive(Clone, Copy, Debug)]
struct Mid {
    op: MidOp,
    start: usize,
    len: usize,
}

/// `state[start .. start + 3 width] += piece · input` (channel-planar).
#[derive(Clone, Debug)]
struct Term {
    start: usize,
    width: usize,
    input: Input,
    piece: Piece,
}

/// `M`'s pieces and the reduced solve's workspace.
#[derive(Clone, Debug)]
pub(super) struct ReducedDrt {
    mids: Vec<Mid>,
    /// `M`'s pieces from the operators' light.
    terms: Vec<Term>,
    /// `M`'s pieces from clutter's implied light (through the gather's clutter reads).
    implied: Vec<Term>,
    /// Per channel, the energy (albedo included) of the operators' light (width 1).
    energy: Vec<Term>,
    /// Planar state: the runtime's `b` layout, then its `c` layout at `n_coef`.
    n_coef: usize,
    /// `(start, width)` of every block's and clutter object's group in the planar state.
    groups: Vec<(usize, usize)>,
    weight: Vec<f32>,
    /// Per clutter object: its uniform albedo when it has gather rows.
    gathering: Vec<Option<[f32; 3]>>,
    gather_views: Vec<GatherView>,
    /// Per clutter object a gather reads: where, and its basis there.
    implieds: Vec<Implied>,
    z_in: Vec<f32>,
    z_out: Vec<f32>,
    /// The implied pieces' output for `c₀` (subtracted from the right-hand side).
    correction: Vec<f32>,
    c0: Vec<f32>,
    mid: Vec<f32>,
    stacked: Vec<f32>,
    /// One clutter object's coefficients, and light on its texels, channel-planar.
    clutter_coef: Vec<f32>,
    planar_texels: Vec<f32>,
    /// Whether the right-hand side's gather of the direct light runs through the gather itself
    /// (into `g0`, per texel) and `t_dc`, not the dense views (whichever reads fewer values).
    rhs_by_gather: bool,
    g0: Vec<[f32; 3]>,
    scratch: Vec<f32>,
    /// Per texel: the light the final gather reads.
    gather_in: Vec<[f32; 3]>,
    krylov: Option<Krylov>,
    rhs: Vec<[f32; 3]>,
    solution: Vec<[f32; 3]>,
    /// The last solve's first-bounce energy per channel (what the light check compares with).
    first_energy: [f64; 3],
}

/// The gather seen from clutter object `clutter`: the texels it reads (ascending block texels,
/// then clutter texels), `t_dc G` over them (m × texels, packed) and `1ᵀ G`'s value per texel.
#[derive(Clone, Debug)]
struct GatherView {
    clutter: usize,
    texels: Vec<u32>,
    columns: PackedMatrix,
    sums: Vec<f32>,
}

/// A clutter object's implied light `B (c − c₀)` where a gather reads it: `B`'s rows of the
/// texels read (ascending), packed.
#[derive(Clone, Debug)]
struct Implied {
    clutter: usize,
    texels: Vec<u32>,
    rows: PackedMatrix,
}

/// Which producers a projector reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Reads {
    /// The operators' light on texels (`y`).
    Light,
    /// A clutter object's implied light.
    Implied,
}

/// Where a projector writes: a state group, or the energy (one value per channel).
#[derive(Clone, Copy, Debug)]
enum Target {
    State { start: usize, width: usize },
    Energy,
}

/// A projector's columns, by global texel.
enum Cols<'a> {
    /// Column `texel − first` of `t` (rows × n, row-major), for texels `first .. first + n`.
    Strided { t: &'a Matrix, first: usize },
    /// One row of ones over every texel.
    Ones,
    /// Columns of the texels listed (ascending), `data[i·r .. (i+1)·r]` for `texels[i]`.
    Dense { texels: Vec<u32>, data: Vec<f32> },
}

struct Projector<'a> {
    target: Target,
    reads: Reads,
    scale: [f32; 3],
    rows: usize,
    cols: Cols<'a>,
}

impl Projector<'_> {
    /// Writes the projector's column for `texel` into `col`; false where it reads nothing.
    fn column(&self, texel: usize, col: &mut [f32]) -> bool {
        match &self.cols {
            Cols::Strided { t, first } => {
                let n = t.cols as usize;
                if texel < *first || texel >= first + n {
                    return false;
                }
                for (a, c) in col.iter_mut().enumerate() {
                    *c = t.data[a * n + texel - first];
                }
                true
            }
            Cols::Ones => {
                col.fill(1.0);
                true
            }
            Cols::Dense { texels, data } => match texels.binary_search(&(texel as u32)) {
                Ok(i) => {
                    col.copy_from_slice(&data[i * self.rows..(i + 1) * self.rows]);
                    true
                }
                Err(_) => false,
            },
        }
    }

    /// `scale ⊙ P diag(ρ) X` over the rows of `x` (row i on texel `texel(i)`, albedo
    /// `albedo(i)`) as its per-albedo sums `(scale ⊙ ρ, P_g)` (r × w each), texels of equal
    /// albedo summed first, in row order; None if the projector reads none of the rows.
    fn piece(
        &self,
        x: &Matrix,
        texel: &dyn Fn(usize) -> usize,
        albedo: &dyn Fn(usize) -> [f32; 3],
    ) -> Option<Groups> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked above); the function has no other contract.
            return unsafe { self.piece_avx2(x, texel, albedo) };
        }
        self.piece_portable(x, texel, albedo)
    }

    /// [`Projector::piece`] compiled for AVX2: the same sums in the same order (each value
    /// accumulates over rows in order; only the width of the vectors across a row differs).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn piece_avx2(
        &self,
        x: &Matrix,
        texel: &dyn Fn(usize) -> usize,
        albedo: &dyn Fn(usize) -> [f32; 3],
    ) -> Option<Groups> {
        self.piece_portable(x, texel, albedo)
    }

    #[inline(always)]
    fn piece_portable(
        &self,
        x: &Matrix,
        texel: &dyn Fn(usize) -> usize,
        albedo: &dyn Fn(usize) -> [f32; 3],
    ) -> Option<Groups> {
        let (r, w) = (self.rows, x.cols as usize);
        let mut col = vec![0.0f32; r];
        let mut order: Vec<usize> = (0..x.rows as usize)
            .filter(|&i| self.column(texel(i), &mut col))
            .collect();
        if order.is_empty() || w == 0 {
            return None;
        }
        order.sort_by_key(|&i| albedo(i).map(f32::to_bits));
        let mut groups: Vec<([f32; 3], Vec<f32>)> = Vec::new();
        for &i in &order {
            let rho = albedo(i);
            if groups.last().is_none_or(|(g, _)| *g != rho) {
                groups.push((rho, vec![0.0; r * w]));
            }
            let (_, sum) = groups.last_mut().expect("pushed above");
            self.column(texel(i), &mut col);
            let row = &x.data[i * w..(i + 1) * w];
            for (a, &v) in col.iter().enumerate() {
                if v != 0.0 {
                    for (s, x) in sum[a * w..(a + 1) * w].iter_mut().zip(row) {
                        *s += v * x;
                    }
                }
            }
        }
        for (rho, _) in &mut groups {
            for (r, s) in rho.iter_mut().zip(self.scale) {
                *r *= s;
            }
        }
        Some(groups)
    }
}

/// A piece before packing: its per-albedo sums `(ρ, P_g)`.
type Groups = Vec<([f32; 3], Vec<f32>)>;

/// A term before packing; terms of one target and input whose albedo groups match are summed
/// into one.
struct RawTerm {
    start: usize,
    width: usize,
    input: Input,
    cols: usize,
    groups: Groups,
}

impl RawTerm {
    fn pack(self) -> Term {
        Term {
            start: self.start,
            width: self.width,
            input: self.input,
            piece: Piece::from_groups(self.width, self.cols, self.groups),
        }
    }
}

/// Adds `t` to `terms`, summed into the term of the same target, input and albedo groups if
/// there is one (`index` finds it).
fn push_merged(
    terms: &mut Vec<RawTerm>,
    index: &mut std::collections::BTreeMap<(usize, usize, Input), usize>,
    t: RawTerm,
) {
    let key = (t.start, t.width, t.input);
    if let Some(&i) = index.get(&key) {
        let same = &mut terms[i];
        let matching = same.cols == t.cols
            && same.groups.len() == t.groups.len()
            && same.groups.iter().zip(&t.groups).all(|(a, b)| a.0 == b.0);
        if matching {
            for ((_, a), (_, b)) in same.groups.iter_mut().zip(&t.groups) {
                a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
            }
            return;
        }
    }
    index.insert(key, terms.len());
    terms.push(t);
}

/// One producer of light on texels: `x`'s row i lies on texel `texel(i)` and multiplies
/// `input`.
struct Producer<'a> {
    x: std::borrow::Cow<'a, Matrix>,
    rows: Rows<'a>,
    input: Input,
    reads: Reads,
}

enum Rows<'a> {
    From(usize),
    List(&'a [u32]),
}

impl Rows<'_> {
    fn texel(&self, i: usize) -> usize {
        match self {
            Rows::From(first) => first + i,
            Rows::List(rows) => rows[i] as usize,
        }
    }
}

/// Per clutter object: its albedo if it has gather rows (None where it has none), and for the
/// block texels (`[0]`) and clutter texels (`[1]`) its gather reads, ascending, `t_dc G`'s
/// column and (last) `1ᵀ G`'s value, summed in f64 in the gather's order. None if a gather
/// row lies outside the clutter, a read outside every unit, or a gathering clutter object has
/// more than one albedo.
#[allow(clippy::type_complexity)]
fn gather_by_clutter(
    bundle: &Bundle,
    owner: &[u32],
    n_blocks: usize,
) -> Option<(Vec<Option<[f32; 3]>>, Vec<[Vec<(u32, Vec<f64>)>; 2]>)> {
    let drt = bundle.drt.as_ref()?;
    let n_clutter = drt.clutter.len();
    let mut gathering: Vec<Option<[f32; 3]>> = vec![None; n_clutter];
    let mut out: Vec<[Vec<(u32, Vec<f64>)>; 2]> =
        (0..n_clutter).map(|_| Default::default()).collect();
    let empty = TexelGather::default();
    let g = drt.direct_gather.as_ref().unwrap_or(&empty);
    let mut rows_of: Vec<Vec<usize>> = vec![Vec::new(); n_clutter];
    // The clutter object of a gather row (its albedo checked), None outside the clutter.
    let clutter_of = |row: u32, gathering: &mut Vec<Option<[f32; 3]>>| {
        let unit = owner[row as usize];
        if unit == NO_UNIT || (unit as usize) < n_blocks {
            return None;
        }
        let j = unit as usize - n_blocks;
        let rho = bundle.layout.albedo[row as usize];
        match gathering[j] {
            None => gathering[j] = Some(rho),
            Some(r) if r != rho => return None,
            Some(_) => {}
        }
        Some(j)
    };
    for (i, &row) in g.rows.iter().enumerate() {
        let j = clutter_of(row, &mut gathering)?;
        rows_of[j].push(i);
    }
    // The gather in low-rank form: per clutter object, (entry, its rows there).
    let mut entries_of: Vec<Vec<(usize, Vec<usize>)>> = vec![Vec::new(); n_clutter];
    for (d, e) in drt.entries.iter().enumerate() {
        let DeltaSource::Direct { first, count } = e.source else {
            continue;
        };
        let range = first as usize..first as usize + count as usize;
        if owner[range].contains(&NO_UNIT) {
            return None;
        }
        for (i, &row) in e.rows.iter().enumerate() {
            let j = clutter_of(row, &mut gathering)?;
            match entries_of[j].last_mut() {
                Some((last, rows)) if *last == d => rows.push(i),
                _ => entries_of[j].push((d, vec![i])),
            }
        }
    }
    // Per clutter object: a slot per texel read (`slot`, reset after), its sums in `data`.
    let mut slot = vec![u32::MAX; owner.len()];
    for (j, rows) in rows_of.iter().enumerate() {
        let c = &drt.clutter[j];
        let (first, n, m) = (
            c.texel_offset as usize,
            c.t_dc.cols as usize,
            c.t_dc.rows as usize,
        );
        // t_dc's columns, contiguous.
        let mut columns = vec![0.0f64; n * m];
        for a in 0..m {
            for t in 0..n {
                columns[t * m + a] = c.t_dc.data[a * n + t] as f64;
            }
        }
        let (mut read, mut data): (Vec<u32>, Vec<f64>) = (Vec::new(), Vec::new());
        for &i in rows {
            let local = g.rows[i] as usize - first;
            let column = &columns[local * m..(local + 1) * m];
            let span = g.row_start[i] as usize..g.row_start[i + 1] as usize;
            for (&col, &v) in g.cols[span.clone()].iter().zip(&g.values[span]) {
                if owner[col as usize] == NO_UNIT {
                    return None;
                }
                if slot[col as usize] == u32::MAX {
                    slot[col as usize] = read.len() as u32;
                    read.push(col);
                    data.extend(std::iter::repeat_n(0.0, m + 1));
                }
                let s = slot[col as usize] as usize * (m + 1);
                let v = v as f64;
                for (d, t) in data[s..s + m].iter_mut().zip(column) {
                    *d += t * v;
                }
                data[s + m] += v;
            }
        }
        for (d, rows) in &entries_of[j] {
            let e = &drt.entries[*d];
            let DeltaSource::Direct { first, count } = e.source else {
                continue;
            };
            // A = t_dc[:, rows] · matrix[rows, :] (m × w) and a = 1ᵀ matrix[rows, :].
            let w = e.matrix.cols as usize;
            let (mut big_a, mut a1) = (vec![0.0f64; m * w], vec![0.0f64; w]);
            for &i in rows {
                let local = e.rows[i] as usize - first_texel(c);
                let column = &columns[local * m..(local + 1) * m];
                let row = &e.matrix.data[i * w..(i + 1) * w];
                for (q, &v) in row.iter().enumerate() {
                    a1[q] += v as f64;
                }
                for (a, &t) in column.iter().enumerate() {
                    for (x, &v) in big_a[a * w..(a + 1) * w].iter_mut().zip(row) {
                        *x += t * v as f64;
                    }
                }
            }
            for t in 0..count as usize {
                let col = first + t as u32;
                if slot[col as usize] == u32::MAX {
                    slot[col as usize] = read.len() as u32;
                    read.push(col);
                    data.extend(std::iter::repeat_n(0.0, m + 1));
                }
                let s = slot[col as usize] as usize * (m + 1);
                // Column t of A · mix (or of A), and of a · mix.
                let weights: Vec<f64> = match &e.mix {
                    Some(mix) => (0..w)
                        .map(|q| mix.data[q * mix.cols as usize + t] as f64)
                        .collect(),
                    None => (0..w).map(|q| f64::from(u8::from(q == t))).collect(),
                };
                for a in 0..m {
                    data[s + a] += big_a[a * w..(a + 1) * w]
                        .iter()
                        .zip(&weights)
                        .map(|(x, y)| x * y)
                        .sum::<f64>();
                }
                data[s + m] += a1.iter().zip(&weights).map(|(x, y)| x * y).sum::<f64>();
            }
        }
        let mut order: Vec<usize> = (0..read.len()).collect();
        order.sort_unstable_by_key(|&i| read[i]);
        for i in order {
            let col = read[i];
            slot[col as usize] = u32::MAX;
            let kind = usize::from(owner[col as usize] as usize >= n_blocks);
            out[j][kind].push((col, data[i * (m + 1)..(i + 1) * (m + 1)].to_vec()));
        }
    }
    Some((gathering, out))
}

/// The operator values one texel-space DRT application reads: every block's `U_b` and
/// `T_d→b`, the transport, the clutter bases, the delta entries and the exact gather.
fn texel_application_values(bundle: &Bundle) -> usize {
    let shapes: usize = bundle
        .blocks
        .iter()
        .map(|b| {
            let s = &bundle.shapes[b.shape as usize];
            s.u_b.data.len() + s.t_db.data.len()
        })
        .sum();
    let transport: usize = match &bundle.transport {
        Some(TransportOps::Compact(e)) => e.iter().map(|e| e.y.data.len() + e.z.data.len()).sum(),
        Some(TransportOps::Traced(e)) => e.iter().map(|e| e.matrix.data.len()).sum(),
        Some(TransportOps::Lightfield(e)) => e.iter().map(|e| e.matrix.data.len()).sum(),
        None => 0,
    };
    let drt = bundle.drt.as_ref().map_or(0, |d| {
        d.clutter.iter().map(|c| c.t_dc.data.len()).sum::<usize>()
            + d.entries
                .iter()
                .map(|e| e.matrix.data.len() + e.mix.as_ref().map_or(0, |m| m.data.len()))
                .sum::<usize>()
            + d.direct_gather.as_ref().map_or(0, |g| g.values.len())
    });
    shapes + transport + drt
}

/// A clutter object's first texel.
fn first_texel(c: &lightfarm_proto::bundle::ClutterOps) -> usize {
    c.texel_offset as usize
}

/// The unit owning each texel: block k is `k`, clutter object j is `n_blocks + j`.
const NO_UNIT: u32 = u32::MAX;

impl ReducedDrt {
    /// `M`'s pieces for `bundle` (None for what the module doc lists as the texel path's).
    /// `gated`: None also when an application of `M` would read more than half a texel
    /// application's values (tests turn it off to reach the path on tiny bundles).
    pub(super) fn new(
        bundle: &Bundle,
        blocks: &[BlockSlots],
        clutter_coef: &[(usize, usize)],
        ops: &PackedOps,
        gated: bool,
    ) -> Option<ReducedDrt> {
        let drt = bundle.drt.as_ref()?;
        if matches!(bundle.transport, Some(TransportOps::Lightfield(_))) || !drt.replaced.is_empty()
        {
            return None;
        }
        let n_texels = bundle.layout.n_texels();
        let albedo = &bundle.layout.albedo;
        let n_blocks = blocks.len();
        let mut owner = vec![NO_UNIT; n_texels];
        for (k, s) in blocks.iter().enumerate() {
            owner[s.texel_start..s.texel_end].fill(k as u32);
        }
        for (j, c) in drt.clutter.iter().enumerate() {
            let first = c.texel_offset as usize;
            owner[first..first + c.t_dc.cols as usize].fill((n_blocks + j) as u32);
        }
        let n_coef = blocks.last().map_or(0, |s| s.coef_start + 3 * s.rank);
        let mut groups: Vec<(usize, usize)> =
            blocks.iter().map(|s| (s.coef_start, s.rank)).collect();
        groups.extend(clutter_coef.iter().map(|&(start, m)| (n_coef + start, m)));

        // The gather seen from each clutter object's coefficients, `t_dc G` (f64 sums), over
        // the block texels and the clutter texels it reads.
        let (gathering, gather_cols) = gather_by_clutter(bundle, &owner, n_blocks)?;

        // Projectors, and which read each unit's texels.
        let mut projectors: Vec<Projector> = Vec::new();
        let mut by_unit: Vec<Vec<usize>> = vec![Vec::new(); n_blocks + drt.clutter.len()];
        for (k, blk) in bundle.blocks.iter().enumerate() {
            by_unit[k].push(projectors.len());
            projectors.push(Projector {
                target: Target::State {
                    start: groups[k].0,
                    width: groups[k].1,
                },
                reads: Reads::Light,
                scale: [1.0; 3],
                rows: groups[k].1,
                cols: Cols::Strided {
                    t: &bundle.shapes[blk.shape as usize].t_db,
                    first: blocks[k].texel_start,
                },
            });
        }
        for (j, c) in drt.clutter.iter().enumerate() {
            let (start, width) = groups[n_blocks + j];
            by_unit[n_blocks + j].push(projectors.len());
            projectors.push(Projector {
                target: Target::State { start, width },
                reads: Reads::Light,
                scale: [1.0; 3],
                rows: width,
                cols: Cols::Strided {
                    t: &c.t_dc,
                    first: c.texel_offset as usize,
                },
            });
        }
        let energy_projector = projectors.len();
        projectors.push(Projector {
            target: Target::Energy,
            reads: Reads::Light,
            scale: [1.0; 3],
            rows: 1,
            cols: Cols::Ones,
        });
        // The gather of the direct light, seen from each clutter object (the right-hand side):
        // every column it reads, its `t_dc G` column and `1ᵀ G` value.
        let mut gather_views: Vec<GatherView> = Vec::new();
        for (j, cols) in gather_cols.into_iter().enumerate() {
            let (start, width) = groups[n_blocks + j];
            let rho = gathering[j].unwrap_or([0.0; 3]);
            let (mut texels_read, mut columns, mut sums) = (Vec::new(), Vec::new(), Vec::new());
            for (kind, cols) in cols.into_iter().enumerate() {
                if cols.is_empty() {
                    continue;
                }
                let id = projectors.len();
                let mut units: Vec<u32> = cols.iter().map(|(t, _)| owner[*t as usize]).collect();
                units.dedup();
                for u in units {
                    if by_unit[u as usize].last() != Some(&id) {
                        by_unit[u as usize].push(id);
                    }
                }
                let texels: Vec<u32> = cols.iter().map(|(t, _)| *t).collect();
                let data: Vec<f32> = cols
                    .iter()
                    .flat_map(|(_, v)| &v[..width])
                    .map(|&v| v as f32)
                    .collect();
                texels_read.extend(&texels);
                columns.extend(&data);
                sums.extend(cols.iter().map(|(_, v)| v[width] as f32));
                projectors.push(Projector {
                    target: Target::State { start, width },
                    reads: if kind == 0 {
                        Reads::Light
                    } else {
                        Reads::Implied
                    },
                    scale: rho,
                    rows: width,
                    cols: Cols::Dense { texels, data },
                });
            }
            // `columns` holds a column per texel: transpose to m × texels.
            let n_read = texels_read.len();
            let mut by_rows = vec![0.0f32; width * n_read];
            for i in 0..n_read {
                for a in 0..width {
                    by_rows[a * n_read + i] = columns[i * width + a];
                }
            }
            let view = GatherView {
                clutter: j,
                texels: texels_read,
                columns: PackedMatrix::f32(&Matrix {
                    rows: width as u32,
                    cols: n_read as u32,
                    data: by_rows,
                }),
                sums,
            };
            if !view.texels.is_empty() {
                gather_views.push(view);
            }
        }

        // Producers, in a fixed order, and the mids they read.
        let mut mids: Vec<Mid> = Vec::new();
        let mut n_mid = 0;
        let mut mid = |op: MidOp, len: usize, mids: &mut Vec<Mid>| {
            mids.push(Mid {
                op,
                start: n_mid,
                len,
            });
            n_mid += 3 * len;
            Input::Mid(mids.len() - 1)
        };
        let mut producers: Vec<Producer> = Vec::new();
        for (k, blk) in bundle.blocks.iter().enumerate() {
            producers.push(Producer {
                x: std::borrow::Cow::Borrowed(&bundle.shapes[blk.shape as usize].u_b),
                rows: Rows::From(blocks[k].texel_start),
                input: Input::Block(k),
                reads: Reads::Light,
            });
        }
        let (mut widest, mut scratch_mats): (usize, Vec<&crate::packed::PackedMatrix>) =
            (0, Vec::new());
        match &bundle.transport {
            Some(TransportOps::Compact(entries)) => {
                for (i, e) in entries.iter().enumerate() {
                    widest = widest.max(e.z.cols as usize);
                    scratch_mats.push(&ops.transport_z[i]);
                    let input = mid(MidOp::Compact(i), e.z.rows as usize, &mut mids);
                    producers.push(Producer {
                        x: std::borrow::Cow::Borrowed(&e.y),
                        rows: Rows::From(blocks[e.target_block as usize].texel_start),
                        input,
                        reads: Reads::Light,
                    });
                }
            }
            Some(TransportOps::Traced(entries)) => {
                for e in entries {
                    producers.push(Producer {
                        x: std::borrow::Cow::Borrowed(&e.matrix),
                        rows: Rows::From(blocks[e.target_block as usize].texel_start),
                        input: Input::Block(e.source_block as usize),
                        reads: Reads::Light,
                    });
                }
            }
            _ => {}
        }
        for (i, e) in drt.entries.iter().enumerate() {
            if matches!(e.source, DeltaSource::Direct { .. }) {
                continue;
            }
            if ops.delta_mix[i].is_none()
                && e.rows.len() < e.matrix.cols as usize
                && !matches!(e.source, DeltaSource::Direct { .. })
            {
                let n = e.rows.len();
                let mut identity = vec![0.0f32; n * n];
                for t in 0..n {
                    identity[t * n + t] = 1.0;
                }
                scratch_mats.push(&ops.deltas[i]);
                producers.push(Producer {
                    x: std::borrow::Cow::Owned(Matrix {
                        rows: n as u32,
                        cols: n as u32,
                        data: identity,
                    }),
                    rows: Rows::List(&e.rows),
                    input: mid(MidOp::Rows(i), n, &mut mids),
                    reads: Reads::Light,
                });
                continue;
            }
            let input = match (&ops.delta_mix[i], e.source) {
                (Some(m), _) => {
                    scratch_mats.push(m);
                    mid(MidOp::Mix(i), m.rows(), &mut mids)
                }
                (None, DeltaSource::Block(k)) => Input::Block(k as usize),
                (None, DeltaSource::Clutter(j)) => Input::Clutter(j as usize),
                // The exact gather in low-rank form: read through the gather's projectors.
                (None, DeltaSource::Direct { .. }) => continue,
            };
            producers.push(Producer {
                x: std::borrow::Cow::Borrowed(&e.matrix),
                rows: Rows::List(&e.rows),
                input,
                reads: Reads::Light,
            });
        }
        let implied_read: Vec<bool> = (0..drt.clutter.len())
            .map(|j| {
                by_unit[n_blocks + j]
                    .iter()
                    .any(|&p| projectors[p].reads == Reads::Implied)
            })
            .collect();
        // Per clutter object a gather reads: the texels read and `B`'s rows there.
        let mut implieds: Vec<Implied> = Vec::new();
        for (j, c) in drt.clutter.iter().enumerate() {
            if !implied_read[j] {
                continue;
            }
            let (first, n, m) = (
                c.texel_offset as usize,
                c.t_dc.cols as usize,
                c.t_dc.rows as usize,
            );
            let mut texels: Vec<u32> = projectors
                .iter()
                .filter(|p| p.reads == Reads::Implied)
                .flat_map(|p| match &p.cols {
                    Cols::Dense { texels, .. } => texels.as_slice(),
                    _ => &[],
                })
                .copied()
                .filter(|&t| (first..first + n).contains(&(t as usize)))
                .collect();
            texels.sort_unstable();
            texels.dedup();
            let mut rows = Vec::with_capacity(texels.len() * m);
            for &t in &texels {
                rows.extend((0..m).map(|a| c.t_dc.data[a * n + t as usize - first]));
            }
            let rows = PackedMatrix::f32(&Matrix {
                rows: texels.len() as u32,
                cols: m as u32,
                data: rows,
            });
            implieds.push(Implied {
                clutter: j,
                texels,
                rows,
            });
        }
        for (j, c) in drt.clutter.iter().enumerate() {
            if !implied_read[j] {
                continue;
            }
            let (m, n) = (c.t_dc.rows as usize, c.t_dc.cols as usize);
            let mut b = vec![0.0f32; n * m];
            for a in 0..m {
                for t in 0..n {
                    b[t * m + a] = c.t_dc.data[a * n + t];
                }
            }
            producers.push(Producer {
                x: std::borrow::Cow::Owned(Matrix {
                    rows: n as u32,
                    cols: m as u32,
                    data: b,
                }),
                rows: Rows::From(c.texel_offset as usize),
                input: Input::Clutter(j),
                reads: Reads::Implied,
            });
        }

        // Every (producer, projector reading its texels) pair is a piece: the pairs first, and
        // only if an application of `M` reads well under half the values of a texel
        // application (else the coefficients buy nothing: on a 1,000-block level the compact
        // transport's `Z`, which both paths read, leads both).
        let mut pairs: Vec<Vec<usize>> = Vec::with_capacity(producers.len());
        let mut cost: usize = mids
            .iter()
            .map(|m| match m.op {
                MidOp::Compact(i) => ops.transport_z[i].rows() * ops.transport_z[i].cols(),
                MidOp::Mix(i) => ops.delta_mix[i].as_ref().map_or(0, |x| x.rows() * x.cols()),
                MidOp::Rows(i) => ops.deltas[i].rows() * ops.deltas[i].cols(),
            })
            .sum();
        for p in &producers {
            let mut candidates: Vec<usize> = Vec::new();
            let mut last = NO_UNIT;
            for i in 0..p.x.rows as usize {
                let u = owner[p.rows.texel(i)];
                if u != last && u != NO_UNIT {
                    candidates.extend(&by_unit[u as usize]);
                    last = u;
                }
            }
            if p.reads == Reads::Light {
                candidates.push(energy_projector);
            }
            candidates.sort_unstable();
            candidates.dedup();
            candidates.retain(|&id| projectors[id].reads == p.reads);
            cost += candidates
                .iter()
                .filter(|&&id| !matches!(projectors[id].target, Target::Energy))
                .map(|&id| projectors[id].rows * p.x.cols as usize)
                .sum::<usize>();
            pairs.push(candidates);
        }
        if gated && 2 * cost > texel_application_values(bundle) {
            return None;
        }
        let (mut terms, mut implied, mut energy) = (Vec::new(), Vec::new(), Vec::new());
        let (mut terms_index, mut implied_index, mut energy_index) = Default::default();
        for (p, candidates) in producers.iter().zip(&pairs) {
            let texel = |i: usize| p.rows.texel(i);
            let ones = |_: usize| [1.0f32; 3];
            let rho = |i: usize| albedo[p.rows.texel(i)];
            let albedo_of: &dyn Fn(usize) -> [f32; 3] = match p.reads {
                Reads::Light => &rho,
                Reads::Implied => &ones,
            };
            for &id in candidates {
                let proj = &projectors[id];
                let Some(groups) = proj.piece(&p.x, &texel, albedo_of) else {
                    continue;
                };
                let term = |start, width| RawTerm {
                    start,
                    width,
                    input: p.input,
                    cols: p.x.cols as usize,
                    groups,
                };
                match (proj.target, p.reads) {
                    (Target::Energy, _) => push_merged(&mut energy, &mut energy_index, term(0, 1)),
                    (Target::State { start, width }, Reads::Light) => {
                        push_merged(&mut terms, &mut terms_index, term(start, width))
                    }
                    (Target::State { start, width }, Reads::Implied) => {
                        push_merged(&mut implied, &mut implied_index, term(start, width))
                    }
                }
            }
        }
        let pack = |t: Vec<RawTerm>| t.into_iter().map(RawTerm::pack).collect::<Vec<Term>>();
        let (terms, implied, energy) = (pack(terms), pack(implied), pack(energy));

        let n_state = n_coef + clutter_coef.last().map_or(0, |&(s, m)| s + 3 * m);
        let mut weight = block_weights(bundle, blocks, n_state / 3);
        weight[n_coef / 3..].fill(1.0);
        let deepest_clutter = drt.clutter.iter().map(|c| c.t_dc.rows as usize).max();
        let scratch = PackedOps::scratch_len(
            terms
                .iter()
                .chain(&implied)
                .chain(&energy)
                .flat_map(|t| t.piece.packed())
                .chain(scratch_mats)
                .chain(&ops.clutter),
        );
        let has_gather = !gather_views.is_empty();
        let views_values: usize = gather_views
            .iter()
            .map(|v| v.columns.rows() * v.columns.cols())
            .sum();
        let gather_values = drt.direct_gather.as_ref().map_or(0, |g| g.values.len())
            + drt
                .entries
                .iter()
                .filter(|e| matches!(e.source, DeltaSource::Direct { .. }))
                .map(|e| e.matrix.data.len() + e.mix.as_ref().map_or(0, |m| m.data.len()))
                .sum::<usize>()
            + drt
                .clutter
                .iter()
                .zip(&gathering)
                .filter(|(_, g)| g.is_some())
                .map(|(c, _)| c.t_dc.data.len())
                .sum::<usize>();
        let rhs_by_gather = has_gather && gather_values < views_values;
        let widest_view = gather_views
            .iter()
            .map(|v| v.texels.len())
            .max()
            .unwrap_or(0);
        let widest_clutter = drt.clutter.iter().map(|c| c.t_dc.cols as usize).max();
        Some(ReducedDrt {
            mids,
            terms,
            implied,
            energy,
            n_coef,
            groups,
            weight,
            gathering,
            gather_views,
            implieds,
            z_in: vec![0.0; n_state],
            z_out: vec![0.0; n_state],
            correction: vec![0.0; n_state],
            c0: vec![0.0; n_state - n_coef],
            mid: vec![0.0; n_mid],
            stacked: vec![0.0; 3 * widest],
            clutter_coef: vec![0.0; 3 * deepest_clutter.unwrap_or(0)],
            planar_texels: vec![0.0; 3 * widest_clutter.unwrap_or(0).max(widest_view)],
            rhs_by_gather,
            g0: vec![[0.0; 3]; if rhs_by_gather { n_texels } else { 0 }],
            scratch: vec![0.0; scratch],
            gather_in: vec![[0.0; 3]; if has_gather { n_texels } else { 0 }],
            krylov: Some(Krylov::new(n_state / 3)),
            rhs: vec![[0.0; 3]; n_state / 3],
            solution: vec![[0.0; 3]; n_state / 3],
            first_energy: [0.0; 3],
        })
    }

    /// Fills the mids from the planar state `z_in`.
    fn make_mids(&mut self, bundle: &Bundle, blocks: &[BlockSlots], ops: &PackedOps) {
        let ReducedDrt {
            mids,
            groups,
            z_in,
            mid,
            stacked,
            scratch,
            ..
        } = self;
        for m in mids.iter() {
            let dst = &mut mid[m.start..m.start + 3 * m.len];
            match m.op {
                MidOp::Compact(i) => {
                    let Some(TransportOps::Compact(entries)) = &bundle.transport else {
                        continue;
                    };
                    let width = entries[i].z.cols as usize;
                    stack_sources(blocks, z_in, &entries[i].sources, width, stacked, |_| true);
                    let x = planar(stacked, width, 0, width);
                    set_matvec(dst, m.len, &ops.transport_z[i], x, scratch);
                }
                MidOp::Mix(i) | MidOp::Rows(i) => {
                    let matrix = match m.op {
                        MidOp::Mix(_) => ops.delta_mix[i].as_ref(),
                        _ => Some(&ops.deltas[i]),
                    };
                    let (Some(matrix), Some(drt)) = (matrix, &bundle.drt) else {
                        continue;
                    };
                    let (start, width) = match drt.entries[i].source {
                        DeltaSource::Block(k) => groups[k as usize],
                        DeltaSource::Clutter(j) => groups[blocks.len() + j as usize],
                        DeltaSource::Direct { .. } => continue,
                    };
                    let x = group(z_in, start, width, matrix.cols());
                    set_matvec(dst, m.len, matrix, x, scratch);
                }
            }
        }
    }

    /// `out += Σ terms · inputs` over the planar state `z_in` and the mids.
    fn add_terms(
        terms: &[Term],
        groups: &[(usize, usize)],
        n_blocks: usize,
        mids: &[Mid],
        (z_in, mid): (&[f32], &[f32]),
        out: &mut [f32],
        scratch: &mut [f32],
    ) {
        for t in terms {
            let x = match t.input {
                Input::Block(k) => {
                    let (start, width) = groups[k];
                    group(z_in, start, width, width)
                }
                Input::Clutter(j) => {
                    let (start, width) = groups[n_blocks + j];
                    group(z_in, start, width, width)
                }
                Input::Mid(i) => group(mid, mids[i].start, mids[i].len, mids[i].len),
            };
            t.piece.add(
                t.width,
                x,
                &mut out[t.start..t.start + 3 * t.width],
                scratch,
            );
        }
    }

    /// `w = M v` over weighted RGB state vectors.
    fn apply(
        &mut self,
        bundle: &Bundle,
        blocks: &[BlockSlots],
        ops: &PackedOps,
        v: &[[f32; 3]],
        w: &mut [[f32; 3]],
    ) {
        to_planar(&self.groups, &self.weight, v, &mut self.z_in);
        self.make_mids(bundle, blocks, ops);
        self.z_out.fill(0.0);
        let ReducedDrt {
            terms,
            implied,
            groups,
            mids,
            z_in,
            mid,
            z_out,
            scratch,
            ..
        } = self;
        let n_blocks = blocks.len();
        for t in [&*terms, &*implied] {
            ReducedDrt::add_terms(t, groups, n_blocks, mids, (z_in, mid), z_out, scratch);
        }
        from_planar(&self.groups, &self.weight, &self.z_out, w);
    }
}

/// Weighted RGB state (index `start / 3 + i` of each group) → planar state.
fn to_planar(groups: &[(usize, usize)], weight: &[f32], v: &[[f32; 3]], z: &mut [f32]) {
    for &(start, width) in groups {
        let base = start / 3;
        for i in 0..width {
            for c in 0..3 {
                z[start + c * width + i] = v[base + i][c] / weight[base + i];
            }
        }
    }
}

/// Planar state → weighted RGB state (the inverse of [`to_planar`]).
fn from_planar(groups: &[(usize, usize)], weight: &[f32], z: &[f32], v: &mut [[f32; 3]]) {
    for &(start, width) in groups {
        let base = start / 3;
        for i in 0..width {
            for c in 0..3 {
                v[base + i][c] = z[start + c * width + i] * weight[base + i];
            }
        }
    }
}

impl super::Runtime {
    /// Whether DRT's `Converged` solves run in coefficient space (after the first such solve),
    /// and the last one's first-bounce energy per channel (for tests).
    #[cfg(test)]
    pub(super) fn reduced_drt_first_energy(&self) -> Option<[f64; 3]> {
        self.reduced_drt.as_ref().map(|r| r.first_energy)
    }

    /// Takes DRT's coefficient-space path even where it would read as many values as the texel
    /// path (the hand-built test bundles are too small to pass the gate).
    #[cfg(test)]
    pub(super) fn ungate_reduced_drt(&mut self) {
        self.reduced_drt_gated = false;
    }

    /// Switches the right-hand side's gather of the direct light between its two ways (the
    /// views and the gather itself), both exact; false before the first solve.
    #[cfg(test)]
    pub(super) fn switch_reduced_drt_rhs(&mut self) -> bool {
        let n = self.n_texels;
        let Some(red) = self.reduced_drt.as_mut() else {
            return false;
        };
        red.rhs_by_gather = !red.rhs_by_gather;
        red.g0.resize(n, [0.0; 3]);
        true
    }

    /// Makes the DRT pieces once (None for what keeps the texel path); the first DRT
    /// `Converged` solve calls it.
    fn prepare_reduced_drt(&mut self) {
        if !self.reduced_drt_tried {
            self.reduced_drt_tried = true;
            let (bundle, blocks, clutter, ops) =
                (&self.bundle, &self.blocks, &self.clutter_coef, &self.ops);
            self.reduced_drt =
                ReducedDrt::new(bundle, blocks, clutter, ops, self.reduced_drt_gated).map(Box::new);
        }
    }

    /// [`super::Bounces::Converged`] for DRT in coefficient space (the module doc); None when
    /// the bundle keeps the texel path.
    pub(super) fn converge_reduced_drt(
        &mut self,
        direct: &[[f32; 3]],
        out: &mut [[f32; 3]],
        tolerance: f32,
    ) -> Option<Result<super::Applied, super::ApplyError>> {
        use super::MAX_BOUNCES;
        self.prepare_reduced_drt();
        let mut red = self.reduced_drt.take()?;
        // z₀ = (T_d→b L_d, t_dc L_d); relighting by the change, only what it reaches projects.
        if self.reach.is_some() {
            self.find_reach(direct);
        }
        self.project_blocks(direct);
        self.project_clutter();
        let n_coef = red.n_coef;
        red.z_in[..n_coef].copy_from_slice(&self.b[..n_coef]);
        red.z_in[n_coef..].copy_from_slice(&self.c);
        red.c0.copy_from_slice(&self.c);
        // The first bounce's energy: the operators' light from z₀ plus the gather of L_d.
        red.make_mids(&self.bundle, &self.blocks, &self.ops);
        let mut e1 = [0.0f32; 3];
        {
            let n_blocks = self.blocks.len();
            let ReducedDrt {
                energy,
                groups,
                mids,
                z_in,
                mid,
                scratch,
                ..
            } = &mut *red;
            ReducedDrt::add_terms(
                energy,
                groups,
                n_blocks,
                mids,
                (z_in, mid),
                &mut e1,
                scratch,
            );
        }
        let mut e1 = e1.map(f64::from);
        // rhs = z₀ + (0, ρ_j t_dc G L_d) − (implied pieces)(0, c₀).
        red.z_out.copy_from_slice(&red.z_in);
        // The gather of L_d seen from each clutter object, and its energy: by the dense views,
        // or by the gather itself and `t_dc` where that reads fewer values.
        if red.rhs_by_gather {
            let mut g0 = std::mem::take(&mut red.g0);
            g0.fill([0.0; 3]);
            self.add_direct_gather(direct, &mut g0);
            self.add_deltas_of(&mut g0, Deltas::OfLight);
            let drt = self.bundle.drt.as_ref()?;
            for (j, c) in drt.clutter.iter().enumerate() {
                let Some(rho) = red.gathering[j] else {
                    continue;
                };
                let (first, n) = (c.texel_offset as usize, c.t_dc.cols as usize);
                let (start, m) = red.groups[self.blocks.len() + j];
                for (t, g) in g0[first..first + n].iter().enumerate() {
                    for ch in 0..3 {
                        red.planar_texels[ch * n + t] = g[ch];
                        e1[ch] += (rho[ch] * g[ch]) as f64;
                    }
                }
                let ReducedDrt {
                    planar_texels,
                    clutter_coef,
                    scratch,
                    z_out,
                    ..
                } = &mut *red;
                let x = planar(planar_texels, n, 0, n);
                set_matvec(clutter_coef, m, &self.ops.clutter[j], x, scratch);
                for ch in 0..3 {
                    for a in 0..m {
                        z_out[start + ch * m + a] += rho[ch] * clutter_coef[ch * m + a];
                    }
                }
            }
            red.g0 = g0;
        }
        for view in red.gather_views.iter().filter(|_| !red.rhs_by_gather) {
            let Some(rho) = red.gathering[view.clutter] else {
                continue;
            };
            let (start, m) = red.groups[self.blocks.len() + view.clutter];
            let n = view.texels.len();
            let x = &mut red.planar_texels[..3 * n];
            let mut acc = [0.0f32; 3];
            for (i, &t) in view.texels.iter().enumerate() {
                let d = direct[t as usize];
                for ch in 0..3 {
                    x[ch * n + i] = d[ch];
                    acc[ch] += view.sums[i] * d[ch];
                }
            }
            let coef = &mut red.clutter_coef[..3 * m];
            set_matvec(coef, m, &view.columns, planar(x, n, 0, n), &mut red.scratch);
            for ch in 0..3 {
                e1[ch] += (rho[ch] * acc[ch]) as f64;
                for a in 0..m {
                    red.z_out[start + ch * m + a] += rho[ch] * coef[ch * m + a];
                }
            }
        }
        {
            if !red.implied.is_empty() {
                // (0, c₀) into z_in; the implied pieces read clutter coefficients only.
                let ReducedDrt {
                    implied,
                    groups,
                    mids,
                    z_in,
                    mid,
                    z_out,
                    correction,
                    scratch,
                    ..
                } = &mut *red;
                correction.fill(0.0);
                ReducedDrt::add_terms(
                    implied,
                    groups,
                    self.blocks.len(),
                    mids,
                    (z_in, mid),
                    correction,
                    scratch,
                );
                for (r, c) in z_out.iter_mut().zip(correction.iter()) {
                    *r -= c;
                }
            }
        }
        red.first_energy = e1;
        let mut rhs = std::mem::take(&mut red.rhs);
        let mut solution = std::mem::take(&mut red.solution);
        let mut krylov = red.krylov.take().unwrap_or_else(|| Krylov::new(rhs.len()));
        from_planar(&red.groups, &red.weight, &red.z_out, &mut rhs);
        let solved = {
            let (bundle, blocks, ops) = (&self.bundle, &self.blocks, &self.ops);
            krylov.solve(
                &mut |v, w| red.apply(bundle, blocks, ops, v, w),
                &rhs,
                &mut solution,
                tolerance as f64,
                MAX_BOUNCES - 1,
            )
        };
        to_planar(&red.groups, &red.weight, &solution, &mut red.z_in);
        (red.rhs, red.solution, red.krylov) = (rhs, solution, Some(krylov));
        self.b[..n_coef].copy_from_slice(&red.z_in[..n_coef]);
        self.c.copy_from_slice(&red.z_in[n_coef..]);
        // I = D (y(w) + G (L_d + I)), the bounces reaching every block: expand all of them.
        let reach = self.reach.take();
        self.mrt_albedo_free(out);
        self.add_deltas_of(out, Deltas::OfCoefficients);
        if !red.gather_in.is_empty() {
            let mut light = std::mem::take(&mut red.gather_in);
            let albedo = &self.bundle.layout.albedo;
            for (((l, d), o), rho) in light.iter_mut().zip(direct).zip(&*out).zip(albedo) {
                *l = [
                    d[0] + rho[0] * o[0],
                    d[1] + rho[1] * o[1],
                    d[2] + rho[2] * o[2],
                ];
            }
            // Clutter texels a gather reads: the implied light B (c − c₀) of the bounces.
            for imp in &red.implieds {
                let (start, m) = self.clutter_coef[imp.clutter];
                let d = &mut red.clutter_coef[..3 * m];
                for (i, v) in d.iter_mut().enumerate() {
                    *v = self.c[start + i] - red.c0[start + i];
                }
                let x = planar(d, m, 0, m);
                imp.rows.matvec(x, &mut red.scratch, |i, v| {
                    let t = imp.texels[i] as usize;
                    let l = direct[t];
                    light[t] = [l[0] + v[0], l[1] + v[1], l[2] + v[2]];
                });
            }
            // The gather in low-rank form reads the same light, through `ld`.
            let n = self.n_texels;
            for (t, l) in light.iter().enumerate() {
                for (ch, v) in l.iter().enumerate() {
                    self.ld[ch * n + t] = *v;
                }
            }
            self.ld_everywhere = true;
            self.add_deltas_of(out, Deltas::OfLight);
            self.add_direct_gather(&light, out);
            red.gather_in = light;
        }
        self.multiply_albedo(out);
        self.reach = reach;
        self.reduced_drt = Some(red);
        let channel = |c: usize| out.iter().map(|x| x[c] as f64).sum::<f64>();
        let light = self.by_change || (0..3).all(|c| e1[c] <= 0.0 || channel(c) >= 0.99 * e1[c]);
        if solved.is_ok() && !out.iter().flatten().all(|x| x.is_finite()) {
            return Some(Err(super::ApplyError::NonFinite { bounce: 1 }));
        }
        Some(self.converge_outcome(solved, light))
    }
}
