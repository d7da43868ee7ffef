//! How DRT's coefficient-space pieces are made (`ReducedDrt::new`, see the parent module's doc
//! for what they are): the exact gather, sparse rows and low-rank entries alike, seen from each
//! clutter object's coefficients (`t_dc G` per texel it reads, f64 sums); the projectors (a
//! block's `T_d→b`, a clutter object's `t_dc`, those views, the energy's row of ones) and the
//! producers of light (`U_b`, transport entries, delta entries, clutter's implied light); every
//! (producer, projector reading its texels) product, summed per target and input; and the gate
//! that keeps the texel path where the pieces would read as many values as a texel
//! application.
//!
//! Units: a projector maps albedo-weighted light on texels to coefficients; a producer maps
//! coefficients (or a shared product) to albedo-free light on texels.
//!
//! Invariants: projectors and producers are listed in a fixed order, rows of a piece summed in
//! row order within an albedo group (groups by their albedo's bits), so the pieces are the
//! same bits on every machine (AVX2 only widens the sums across a row).

use lightfarm_proto::bundle::{Bundle, DeltaSource, Matrix, TexelGather, TransportOps};

use super::super::packed_ops::{BlockSlots, PackedOps};
use super::super::reduced::{block_weights, Piece};
use super::{GatherView, Implied, Input, Krylov, Mid, MidOp, ReducedDrt, Term};
use crate::packed::PackedMatrix;

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
            for (col, &v) in g.cols[span.clone()].iter().zip(&g.values[span]) {
                // A tile column reads its texels' mean: each texel a share of the weight.
                let (texels, share) = g.column_texels(owner.len(), col);
                for &col in texels {
                    if owner[col as usize] == NO_UNIT {
                        return None;
                    }
                    if slot[col as usize] == u32::MAX {
                        slot[col as usize] = read.len() as u32;
                        read.push(col);
                        data.extend(std::iter::repeat_n(0.0, m + 1));
                    }
                    let s = slot[col as usize] as usize * (m + 1);
                    let v = v as f64 * share;
                    for (d, t) in data[s..s + m].iter_mut().zip(column) {
                        *d += t * v;
                    }
                    data[s + m] += v;
                }
            }
        }
        for (d, rows) in &entries_of[j] {
            let e = &drt.entries[*d];
            let DeltaSource::Direct {
                first: source_first,
                count: source_count,
            } = e.source
            else {
                continue;
            };
            // A = t_dc[:, rows] · matrix[rows, :] (m × w) and a = 1ᵀ matrix[rows, :].
            let w = e.matrix.cols as usize;
            let (mut big_a, mut a1) = (vec![0.0f64; m * w], vec![0.0f64; w]);
            for &i in rows {
                let local = e.rows[i] as usize - first;
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
            for t in 0..source_count as usize {
                let col = source_first + t as u32;
                if slot[col as usize] == u32::MAX {
                    slot[col as usize] = read.len() as u32;
                    read.push(col);
                    data.extend(std::iter::repeat_n(0.0, m + 1));
                }
                let s = slot[col as usize] as usize * (m + 1);
                // Column t of A · mix and of a · mix (without a mix: of A and a).
                let Some(mix) = &e.mix else {
                    for a in 0..m {
                        data[s + a] += big_a[a * w + t];
                    }
                    data[s + m] += a1[t];
                    continue;
                };
                let stride = mix.cols as usize;
                let weight = |q: usize| mix.data[q * stride + t] as f64;
                for a in 0..m {
                    data[s + a] += big_a[a * w..(a + 1) * w]
                        .iter()
                        .enumerate()
                        .map(|(q, x)| x * weight(q))
                        .sum::<f64>();
                }
                data[s + m] += a1
                    .iter()
                    .enumerate()
                    .map(|(q, x)| x * weight(q))
                    .sum::<f64>();
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
        Some(TransportOps::Factored(_)) => {
            unreachable!("kind 3 is unfolded at load (Runtime::try_new)")
        }
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
        let (mut widest, mut scratch_mats): (usize, Vec<&PackedMatrix>) = (0, Vec::new());
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
            if ops.delta_mix[i].is_none() && e.rows.len() < e.matrix.cols as usize {
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
        let texel_values = texel_application_values(bundle);
        if gated && 2 * cost > texel_values {
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
            read_share: cost as f64 / texel_values.max(1) as f64,
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
            light_entries: drt
                .entries
                .iter()
                .any(|e| matches!(e.source, DeltaSource::Direct { .. })),
            krylov: Some(Krylov::new(n_state / 3)),
            rhs: vec![[0.0; 3]; n_state / 3],
            solution: vec![[0.0; 3]; n_state / 3],
            first_energy: [0.0; 3],
        })
    }
}
