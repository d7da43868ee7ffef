//! Operator matrices in the form the per-frame kernels read: row panels, 8-bit where the
//! bundle stored them in 8 bits.
//!
//! A [`PackedMatrix`] holds a row-major `rows × cols` operator as panels of [`PANEL`] rows: panel
//! `p` stores, for every column `j`, the values of rows `p·8 .. p·8 + 8` contiguously (the last
//! panel zero-padded). A matrix-vector product then keeps 8 rows × 3 channels of accumulators in
//! registers for a whole panel and never sums across lanes, which is what makes short rows
//! (ranks of 10–60) fast; the same loop serves wide matrices (T_d→b) and tall ones (U_b).
//!
//! Values are kept in 8 bits when they lie on an 8-bit grid per column or per row — which is
//! exactly what the bundle's u8 codec decodes to (`offset + scale · q`) — so a u8 operator is
//! read at a quarter of the f32 traffic. The test is on the decoded values themselves: every
//! value must be within 1e-3 of a grid step of `offset + scale · q` with the grid recomputed
//! from its line's minimum and maximum; anything else (f32 or f16 matrices) stays f32. The
//! grid error this adds is therefore at most 1e-3 of a quantisation step.
//!
//! Invariants:
//! - [`PackedMatrix::matvec`] visits rows in ascending order and sums each row's terms in column
//!   order, lane by lane; the order is fixed by the code, not the instruction set, so results
//!   are bit-identical on any x86-64 CPU (AVX2 is used where present, at run time) and on other
//!   architectures.
//! - No allocation per call: the 8-bit per-column form needs `3 · cols` floats of scratch, which
//!   the caller passes (see [`PackedMatrix::scratch_len`]).

use std::ops::Range;
use std::sync::Arc;

use lightfarm_proto::bundle::Matrix;

/// Rows per panel (one AVX2 register of f32).
pub const PANEL: usize = 8;

/// How a packed matrix stores its values.
#[derive(Clone, Debug, PartialEq)]
enum Values {
    F32(Vec<f32>),
    /// `value = offset[j] + scale[j] · q` per column j.
    U8Columns {
        q: Vec<u8>,
        offset: Vec<f32>,
        scale: Vec<f32>,
    },
    /// `value = offset[i] + scale[i] · q` per row i.
    U8Rows {
        q: Vec<u8>,
        offset: Vec<f32>,
        scale: Vec<f32>,
    },
    /// `Z' · blockdiag(Q_s)` (compact transport with shared source bases, bundle transport
    /// kind 3): the product is taken as the two, never multiplied out.
    Factored(Box<Factored>),
}

/// `M = Z' · blockdiag(Q_s)`: `x` is cut into the sources' segments (r_s values each), a segment
/// with a basis becomes `Q_s · x_s` (j_s values), one without is taken as it is, and `Z'` reads
/// the results stacked. `Z'` and every `Q_s` keep their own (8-bit or f32) packing, so the
/// product reads the bytes the bundle shipped, not the larger f32 `Z` they unfold to.
#[derive(Clone, Debug, PartialEq)]
pub struct Factored {
    z: PackedMatrix,
    /// Per source in `x` order: its segment's length r_s and its basis, if any (shared by
    /// every receiver of the source).
    sources: Vec<(usize, Option<Arc<PackedMatrix>>)>,
    /// Rows of `Z'`'s input: Σ j_s or r_s.
    width: usize,
}

/// An operator matrix packed for the per-frame kernels (see the module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct PackedMatrix {
    rows: usize,
    cols: usize,
    values: Values,
}

/// Per-line `(offset, scale, q)` if every value of the lines lies on its line's 8-bit grid.
fn on_u8_grid(
    data: &[f32],
    rows: usize,
    cols: usize,
    per_column: bool,
) -> Option<(Vec<f32>, Vec<f32>, Vec<u8>)> {
    let lines = if per_column { cols } else { rows };
    let line = |i: usize, j: usize| if per_column { j } else { i };
    let mut lo = vec![f32::INFINITY; lines];
    let mut hi = vec![f32::NEG_INFINITY; lines];
    for i in 0..rows {
        for j in 0..cols {
            let v = data[i * cols + j];
            let l = line(i, j);
            lo[l] = lo[l].min(v);
            hi[l] = hi[l].max(v);
        }
    }
    let scale: Vec<f32> = lo
        .iter()
        .zip(&hi)
        .map(|(&l, &h)| if h > l { (h - l) / 255.0 } else { 0.0 })
        .collect();
    let mut q = vec![0u8; rows * cols];
    for i in 0..rows {
        for j in 0..cols {
            let v = data[i * cols + j];
            let l = line(i, j);
            let (o, s) = (lo[l], scale[l]);
            let k = if s > 0.0 {
                ((v - o) / s).round().clamp(0.0, 255.0)
            } else {
                0.0
            };
            if (o + s * k - v).abs() > 1e-3 * s {
                return None;
            }
            q[i * cols + j] = k as u8;
        }
    }
    Some((lo, scale, q))
}

/// Reorders a row-major `rows × cols` array into zero-padded row panels.
fn to_panels<T: Copy + Default>(data: &[T], rows: usize, cols: usize) -> Vec<T> {
    let panels = rows.div_ceil(PANEL);
    let mut out = vec![T::default(); panels * cols * PANEL];
    for i in 0..rows {
        let (p, lane) = (i / PANEL, i % PANEL);
        for j in 0..cols {
            out[(p * cols + j) * PANEL + lane] = data[i * cols + j];
        }
    }
    out
}

impl PackedMatrix {
    /// Packs `m`, in 8 bits when its values lie on an 8-bit grid (see the module doc) and that
    /// is smaller than f32.
    pub fn new(m: &Matrix) -> PackedMatrix {
        let (rows, cols) = (m.rows as usize, m.cols as usize);
        // The bundle's u8 codec uses per-column parameters when cols ≤ rows; try that first.
        let order = if cols <= rows {
            [true, false]
        } else {
            [false, true]
        };
        for per_column in order {
            if rows * cols == 0 {
                break;
            }
            let lines = if per_column { cols } else { rows };
            if rows * cols + 8 * lines >= 4 * rows * cols {
                continue; // the per-line parameters would cost more than they save
            }
            if let Some((offset, scale, q)) = on_u8_grid(&m.data, rows, cols, per_column) {
                let q = to_panels(&q, rows, cols);
                let values = if per_column {
                    Values::U8Columns { q, offset, scale }
                } else {
                    Values::U8Rows { q, offset, scale }
                };
                return PackedMatrix { rows, cols, values };
            }
        }
        PackedMatrix {
            rows,
            cols,
            values: Values::F32(to_panels(&m.data, rows, cols)),
        }
    }

    /// Packs `m` in f32, without looking for an 8-bit grid (for values computed at run time,
    /// which lie on none).
    pub fn f32(m: &Matrix) -> PackedMatrix {
        let (rows, cols) = (m.rows as usize, m.cols as usize);
        PackedMatrix {
            rows,
            cols,
            values: Values::F32(to_panels(&m.data, rows, cols)),
        }
    }

    /// `z · blockdiag(Q_s)` for the sources `(r_s, basis)` in order (a source without a basis
    /// reads its r_s values as they are): `z` is packed like any matrix, and must have
    /// Σ (j_s or r_s) columns.
    pub fn factored(z: &Matrix, sources: Vec<(usize, Option<Arc<PackedMatrix>>)>) -> PackedMatrix {
        let width = sources
            .iter()
            .map(|(r, q)| q.as_ref().map_or(*r, |q| q.rows))
            .sum();
        assert_eq!(
            width, z.cols as usize,
            "Z' has one column per basis coefficient"
        );
        PackedMatrix {
            rows: z.rows as usize,
            cols: sources.iter().map(|(r, _)| r).sum(),
            values: Values::Factored(Box::new(Factored {
                z: PackedMatrix::new(z),
                sources,
                width,
            })),
        }
    }

    pub fn rows(&self) -> usize {
        self.rows
    }

    pub fn cols(&self) -> usize {
        self.cols
    }

    /// Whether the values are kept in 8 bits (a factored matrix: its `Z'`).
    pub fn is_u8(&self) -> bool {
        match &self.values {
            Values::F32(_) => false,
            Values::Factored(f) => f.z.is_u8(),
            _ => true,
        }
    }

    /// Bytes one product reads (values and per-line parameters).
    pub fn bytes(&self) -> usize {
        match &self.values {
            Values::F32(v) => 4 * v.len(),
            Values::U8Columns { q, offset, .. } | Values::U8Rows { q, offset, .. } => {
                q.len() + 8 * offset.len()
            }
            Values::Factored(f) => {
                f.z.bytes()
                    + f.sources
                        .iter()
                        .flat_map(|(_, q)| q)
                        .map(|q| q.bytes())
                        .sum::<usize>()
            }
        }
    }

    /// Floats of scratch [`PackedMatrix::matvec`] needs.
    pub fn scratch_len(&self) -> usize {
        match &self.values {
            Values::U8Columns { .. } => 3 * self.cols,
            Values::Factored(f) => {
                let inner = f
                    .sources
                    .iter()
                    .flat_map(|(_, q)| q)
                    .map(|q| q.scratch_len());
                3 * f.width + inner.chain([f.z.scratch_len()]).max().unwrap_or(0)
            }
            _ => 0,
        }
    }

    /// `out[c][i] = M.row(i) · x[c]` for every row (a non-generic [`PackedMatrix::matvec`], so
    /// that a factored matrix's inner products instantiate nothing new).
    fn matvec_into(&self, x: [&[f32]; 3], scratch: &mut [f32], out: [&mut [f32]; 3]) {
        let [o0, o1, o2] = out;
        self.matvec(x, scratch, |i, v| {
            o0[i] = v[0];
            o1[i] = v[1];
            o2[i] = v[2];
        });
    }

    /// For every row i in ascending order, `emit(i, [M.row(i) · x[0], · x[1], · x[2]])`.
    /// `x[c]` must hold at least `cols` values; `scratch` at least
    /// [`PackedMatrix::scratch_len`].
    #[inline]
    pub fn matvec<E: FnMut(usize, [f32; 3])>(&self, x: [&[f32]; 3], scratch: &mut [f32], emit: E) {
        self.matvec_columns(x, std::slice::from_ref(&(0..self.cols)), scratch, emit)
    }

    /// [`PackedMatrix::matvec`] when `x` is zero in every channel outside `columns` (ascending,
    /// disjoint ranges of columns): only those columns are read, and every row's value is the
    /// whole product's bit for bit (a skipped term `v · 0` is a zero, which leaves a sum that
    /// started at `+0` as it is). A factored matrix reads every column.
    #[inline]
    pub fn matvec_columns<E: FnMut(usize, [f32; 3])>(
        &self,
        x: [&[f32]; 3],
        columns: &[Range<usize>],
        scratch: &mut [f32],
        emit: E,
    ) {
        if self.rows == 0 {
            return;
        }
        if let Values::Factored(f) = &self.values {
            return f.matvec(x, scratch, emit);
        }
        debug_assert!(columns
            .iter()
            .all(|r| r.start <= r.end && r.end <= self.cols));
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked above); the function has no other contract.
            return unsafe { self.matvec_avx2(x, columns, scratch, emit) };
        }
        self.matvec_portable(x, columns, scratch, emit)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn matvec_avx2<E: FnMut(usize, [f32; 3])>(
        &self,
        x: [&[f32]; 3],
        columns: &[Range<usize>],
        scratch: &mut [f32],
        emit: E,
    ) {
        self.matvec_portable(x, columns, scratch, emit)
    }

    #[inline(always)]
    fn matvec_portable<E: FnMut(usize, [f32; 3])>(
        &self,
        x: [&[f32]; 3],
        columns: &[Range<usize>],
        scratch: &mut [f32],
        mut emit: E,
    ) {
        let (rows, cols) = (self.rows, self.cols);
        if cols == 0 {
            for i in 0..rows {
                emit(i, [0.0; 3]);
            }
            return;
        }
        let (x0, x1, x2) = (&x[0][..cols], &x[1][..cols], &x[2][..cols]);
        let each_column = || columns.iter().flat_map(Range::clone);
        match &self.values {
            Values::F32(v) => {
                for (p, panel) in v.chunks_exact(cols * PANEL).enumerate() {
                    let acc = panel_sum(panel, x0, x1, x2, columns, |v: f32| v);
                    for lane in 0..PANEL.min(rows - p * PANEL) {
                        emit(p * PANEL + lane, [acc[0][lane], acc[1][lane], acc[2][lane]]);
                    }
                }
            }
            Values::U8Columns { q, offset, scale } => {
                // value = o_j + s_j q: Σ_j (o_j + s_j q_ij) x_j = Σ_j q_ij (s_j x_j) + Σ_j o_j x_j.
                let (xs, rest) = scratch[..3 * cols].split_at_mut(cols);
                let (ys, zs) = rest.split_at_mut(cols);
                let mut constant = [0.0f32; 3];
                for j in each_column() {
                    xs[j] = scale[j] * x0[j];
                    ys[j] = scale[j] * x1[j];
                    zs[j] = scale[j] * x2[j];
                    constant[0] += offset[j] * x0[j];
                    constant[1] += offset[j] * x1[j];
                    constant[2] += offset[j] * x2[j];
                }
                for (p, panel) in q.chunks_exact(cols * PANEL).enumerate() {
                    let acc = panel_sum(panel, xs, ys, zs, columns, |v: u8| v as f32);
                    for lane in 0..PANEL.min(rows - p * PANEL) {
                        emit(
                            p * PANEL + lane,
                            [
                                acc[0][lane] + constant[0],
                                acc[1][lane] + constant[1],
                                acc[2][lane] + constant[2],
                            ],
                        );
                    }
                }
            }
            Values::U8Rows { q, offset, scale } => {
                // value = o_i + s_i q: row_i · x = s_i Σ_j q_ij x_j + o_i Σ_j x_j.
                let mut total = [0.0f32; 3];
                for j in each_column() {
                    total[0] += x0[j];
                    total[1] += x1[j];
                    total[2] += x2[j];
                }
                for (p, panel) in q.chunks_exact(cols * PANEL).enumerate() {
                    let acc = panel_sum(panel, x0, x1, x2, columns, |v: u8| v as f32);
                    for lane in 0..PANEL.min(rows - p * PANEL) {
                        let i = p * PANEL + lane;
                        let (o, s) = (offset[i], scale[i]);
                        emit(
                            i,
                            [
                                s * acc[0][lane] + o * total[0],
                                s * acc[1][lane] + o * total[1],
                                s * acc[2][lane] + o * total[2],
                            ],
                        );
                    }
                }
            }
            Values::Factored(f) => f.matvec(x, scratch, emit),
        }
    }
}

/// Runs of `Z'`'s columns [`Factored::matvec`] lists at most before it reads them all.
const FACTORED_RUNS: usize = 16;

impl Factored {
    /// `Z' · (blockdiag(Q_s) · x)`, the inner product into the front of `scratch`. A source
    /// whose segment of `x` is zero in every channel (a source block without light) makes no
    /// product: its part of the inner product is zero, and `Z'` reads only the other sources'
    /// columns ([`PackedMatrix::matvec_columns`], the same bits).
    fn matvec<E: FnMut(usize, [f32; 3])>(&self, x: [&[f32]; 3], scratch: &mut [f32], emit: E) {
        let w = self.width;
        let (c, rest) = scratch.split_at_mut(3 * w);
        let (c0, c12) = c.split_at_mut(w);
        let (c1, c2) = c12.split_at_mut(w);
        let (mut from, mut to) = (0, 0);
        let mut runs: [Range<usize>; FACTORED_RUNS] = std::array::from_fn(|_| 0..0);
        let mut n_runs = 0usize;
        let mut every_column = false;
        for (r, q) in &self.sources {
            let seg = |ch: usize| &x[ch][from..from + r];
            let width = q.as_ref().map_or(*r, |q| q.rows);
            if (0..3).all(|ch| seg(ch).iter().all(|&v| v == 0.0)) {
                c0[to..to + width].fill(0.0);
                c1[to..to + width].fill(0.0);
                c2[to..to + width].fill(0.0);
                to += width;
                from += r;
                continue;
            }
            match n_runs.checked_sub(1).map(|i| &mut runs[i]) {
                Some(last) if last.end == to => last.end = to + width,
                _ if n_runs < FACTORED_RUNS => {
                    runs[n_runs] = to..to + width;
                    n_runs += 1;
                }
                _ => every_column = true,
            }
            match q {
                Some(q) => {
                    let j = q.rows;
                    q.matvec_into(
                        [seg(0), seg(1), seg(2)],
                        rest,
                        [
                            &mut c0[to..to + j],
                            &mut c1[to..to + j],
                            &mut c2[to..to + j],
                        ],
                    );
                    to += j;
                }
                None => {
                    c0[to..to + r].copy_from_slice(seg(0));
                    c1[to..to + r].copy_from_slice(seg(1));
                    c2[to..to + r].copy_from_slice(seg(2));
                    to += r;
                }
            }
            from += r;
        }
        let all = 0..w;
        let columns = if every_column {
            std::slice::from_ref(&all)
        } else {
            &runs[..n_runs]
        };
        self.z.matvec_columns([c0, c1, c2], columns, rest, emit)
    }
}

/// `acc[c][lane] = Σ_j value(panel[j·8 + lane]) · x_c[j]` over the columns j of `columns`,
/// ascending. Multiply, then add: a fused multiply-add (AVX2 + FMA copy) measured no faster on
/// the maze's one-light update (its operators' part, eight interleaved runs each: median 0.866
/// against 0.877 ms) and would change every product's bits.
#[inline(always)]
fn panel_sum<T: Copy>(
    panel: &[T],
    x0: &[f32],
    x1: &[f32],
    x2: &[f32],
    columns: &[Range<usize>],
    value: impl Fn(T) -> f32,
) -> [[f32; PANEL]; 3] {
    let mut acc = [[0.0f32; PANEL]; 3];
    for r in columns {
        let panel = &panel[r.start * PANEL..r.end * PANEL];
        let (x0, x1, x2) = (&x0[r.clone()], &x1[r.clone()], &x2[r.clone()]);
        for (((column, &a), &b), &c) in panel.chunks_exact(PANEL).zip(x0).zip(x1).zip(x2) {
            for lane in 0..PANEL {
                let v = value(column[lane]);
                acc[0][lane] += v * a;
                acc[1][lane] += v * b;
                acc[2][lane] += v * c;
            }
        }
    }
    acc
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::codec::{round_trip, MatrixCodec};

    fn matrix(rows: usize, cols: usize, seed: u64) -> Matrix {
        let mut s = seed;
        let data = (0..rows * cols)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect();
        Matrix {
            rows: rows as u32,
            cols: cols as u32,
            data,
        }
    }

    fn reference(m: &Matrix, x: [&[f32]; 3]) -> Vec<[f64; 3]> {
        let cols = m.cols as usize;
        (0..m.rows as usize)
            .map(|i| {
                let mut s = [0.0f64; 3];
                for j in 0..cols {
                    for c in 0..3 {
                        s[c] += m.data[i * cols + j] as f64 * x[c][j] as f64;
                    }
                }
                s
            })
            .collect()
    }

    fn product(p: &PackedMatrix, x: [&[f32]; 3]) -> Vec<[f32; 3]> {
        let mut scratch = vec![0.0; p.scratch_len()];
        let mut out = vec![[f32::NAN; 3]; p.rows()];
        let mut next = 0;
        p.matvec(x, &mut scratch, |i, v| {
            assert_eq!(i, next, "rows are visited in ascending order");
            next += 1;
            out[i] = v;
        });
        assert_eq!(next, p.rows());
        out
    }

    /// Every storage form (f32, u8 per column, u8 per row) against an f64 product, on shapes
    /// with a partial last panel and a single column.
    #[test]
    fn products_match_f64_in_every_form() {
        for (rows, cols) in [
            (1, 1),
            (7, 3),
            (8, 50),
            (19, 1),
            (53, 17),
            (40, 320),
            (5, 0),
        ] {
            let m = matrix(rows, cols, (rows * 1000 + cols) as u64);
            let x: Vec<Vec<f32>> = (0..3).map(|c| matrix(1, cols, 7 + c).data).collect();
            let x = [&x[0][..], &x[1][..], &x[2][..]];
            for codec in [
                MatrixCodec::F32,
                MatrixCodec::U8Columns,
                MatrixCodec::U8Rows,
            ] {
                let decoded = Matrix {
                    data: round_trip(&m.data, rows, cols, codec),
                    ..m.clone()
                };
                let packed = PackedMatrix::new(&decoded);
                let lines = if codec == MatrixCodec::U8Columns {
                    cols
                } else {
                    rows
                };
                let pays = rows * cols + 8 * lines < 4 * rows * cols;
                if codec != MatrixCodec::F32 && pays {
                    assert!(packed.is_u8(), "{rows}×{cols} {codec:?} kept in 8 bits");
                    assert!(packed.bytes() < 4 * rows * cols + 8 * (rows + cols));
                } else if rows.min(cols) > 1 {
                    assert!(!packed.is_u8(), "{rows}×{cols} random f32 is not on a grid");
                }
                let want = reference(&decoded, x);
                let got = product(&packed, x);
                for (g, w) in got.iter().zip(&want) {
                    for c in 0..3 {
                        let tol = 1e-5 * (1.0 + cols as f64);
                        assert!(
                            (g[c] as f64 - w[c]).abs() < tol,
                            "{rows}×{cols} {codec:?}: {} vs {}",
                            g[c],
                            w[c]
                        );
                    }
                }
            }
        }
    }

    /// A constant line (scale 0) and an all-zero matrix stay exact.
    #[test]
    fn constant_lines_are_exact() {
        let m = Matrix {
            rows: 9,
            cols: 2,
            data: (0..18)
                .map(|k| if k % 2 == 0 { 0.25 } else { -1.5 })
                .collect(),
        };
        let p = PackedMatrix::new(&m);
        assert!(p.is_u8());
        let out = product(&p, [&[1.0, 2.0], &[0.0, 1.0], &[4.0, 0.0]]);
        for v in out {
            assert_eq!(v, [0.25 - 3.0, -1.5, 1.0]);
        }
        let zero = PackedMatrix::new(&Matrix::zeros(3, 4));
        assert_eq!(
            product(&zero, [&[1.0; 4], &[1.0; 4], &[1.0; 4]]),
            vec![[0.0; 3]; 3]
        );
    }

    /// `m` through each codec the packing keeps apart (f32, 8 bits per column, per row),
    /// packed, with its scratch.
    fn in_every_storage(
        m: &Matrix,
    ) -> impl Iterator<Item = (MatrixCodec, PackedMatrix, Vec<f32>)> + '_ {
        [
            MatrixCodec::F32,
            MatrixCodec::U8Columns,
            MatrixCodec::U8Rows,
        ]
        .into_iter()
        .map(|codec| {
            let decoded = Matrix {
                data: round_trip(&m.data, m.rows as usize, m.cols as usize, codec),
                ..m.clone()
            };
            let p = PackedMatrix::new(&decoded);
            let scratch = vec![0.0; p.scratch_len()];
            (codec, p, scratch)
        })
    }

    /// The AVX2 and portable builds give the same bits.
    #[test]
    fn dispatch_is_bit_identical() {
        let m = matrix(37, 29, 3);
        let x: Vec<Vec<f32>> = (0..3).map(|c| matrix(1, 29, 11 + c).data).collect();
        let x = [&x[0][..], &x[1][..], &x[2][..]];
        for (_, p, mut scratch) in in_every_storage(&m) {
            let (mut a, mut b) = (Vec::new(), Vec::new());
            p.matvec(x, &mut scratch, |_, v| a.push(v));
            let every = 0..29;
            p.matvec_portable(x, std::slice::from_ref(&every), &mut scratch, |_, v| {
                b.push(v)
            });
            assert_eq!(a, b);
        }
    }

    /// With the input zero outside some runs of columns (one channel alone non-zero in
    /// places, negative values in the matrix), reading those runs alone gives every row's
    /// value bit for bit, in every storage.
    #[test]
    fn reading_the_non_zero_columns_alone_gives_the_same_bits() {
        let m = matrix(37, 29, 5);
        let mut x: Vec<Vec<f32>> = (0..3).map(|c| matrix(1, 29, 21 + c).data).collect();
        let runs = [2..5, 9..10, 17..26];
        for j in 0..29 {
            if !runs.iter().any(|r| r.contains(&j)) {
                for ch in x.iter_mut() {
                    ch[j] = 0.0;
                }
            }
        }
        // Column 9 carries light in the green channel only.
        x[0][9] = 0.0;
        x[2][9] = 0.0;
        let x = [&x[0][..], &x[1][..], &x[2][..]];
        for (codec, p, mut scratch) in in_every_storage(&m) {
            let (mut whole, mut some) = (Vec::new(), Vec::new());
            p.matvec(x, &mut scratch, |_, v| whole.push(v.map(f32::to_bits)));
            p.matvec_columns(x, &runs, &mut scratch, |_, v| {
                some.push(v.map(f32::to_bits))
            });
            assert_eq!(whole.len(), 37);
            assert_eq!(whole, some, "{codec:?}");
            // The runs matter: without the last one the rows change.
            let mut fewer = Vec::new();
            p.matvec_columns(x, &runs[..2], &mut scratch, |_, v| {
                fewer.push(v.map(f32::to_bits))
            });
            assert_ne!(whole, fewer, "{codec:?}");
        }
    }
}
