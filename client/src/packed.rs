//! Operator matrices in the form the per-frame kernels read: row panels, 8-bit where the
//! bundle stored them in 8 bits.
//!
//! A [`PackedMatrix`] holds a row-major `rows × cols` operator as panels of [`PANEL`] = 16 rows:
//! panel `p` stores, for every column `j`, the values of rows `16p .. 16p + 16` contiguously
//! (the last panel zero-padded). A matrix-vector product then keeps 16 rows × 3 channels of
//! accumulators in registers for a whole panel (three AVX-512 registers, or six AVX2 ones) and
//! never sums across lanes, which is what makes short rows (ranks of 10–60) fast; the same loop
//! serves wide matrices (T_d→b) and tall ones (U_b). Each channel's sum of a column is a
//! dependent add, so the rows a panel carries are what the loop gets per add's latency: 16-row
//! panels in explicit AVX-512 / AVX2 kernels made the maze's whole apply's operators 1.83–1.96
//! → 1.66–1.79 ms and its all-bounce update's 4.48–4.57 → 3.82–3.86 ms (one thread, with the
//! 8-bit floored grids below; `frame-time`, medians, interleaved runs).
//!
//! Values are kept in 8 bits when they lie on an 8-bit grid per column or per row — which is
//! exactly what the bundle's u8 codec decodes to (`offset + scale · q`) — so a u8 operator is
//! read at a quarter of the f32 traffic. The test is on the decoded values themselves: every
//! value must be within 1e-3 of a grid step of `offset + scale · q`, with the grid found from
//! its line's values: the line's minimum and maximum on all 256 levels, or (the encoder's
//! floored steps and coarser grids, which use fewer) the step of the smallest gap between its
//! values; anything else (f32 or f16 matrices) stays f32. The grid error this adds is
//! therefore at most 1e-3 of a quantisation step. The floored steps are what the bundle
//! writer gives DRT's delta entries: until they were recognised here those entries (1.34 M
//! values on the maze) were unpacked to f32, 55% of the bytes a one-light frame read.
//!
//! Invariants:
//! - [`PackedMatrix::matvec`] visits rows in ascending order and sums each row's terms in column
//!   order, lane by lane, multiplying then adding (no fused multiply-add); the order is fixed
//!   by the code, not the instruction set, so results are bit-identical on any x86-64 CPU
//!   (AVX-512F or AVX2 is used where present, at run time) and on other architectures.
//! - No allocation per call: the 8-bit per-column form needs `3 · cols` floats of scratch, which
//!   the caller passes (see [`PackedMatrix::scratch_len`]).

use std::ops::Range;
use std::sync::Arc;

use lightfarm_proto::bundle::Matrix;

/// Rows per panel (one AVX-512 register of f32, two AVX2 ones).
pub const PANEL: usize = 16;

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

/// Largest relative distance of a value from its line's grid point that still counts as on it.
const ON_GRID: f32 = 1e-3;

/// The 8-bit grid `(offset, scale)` one line's values lie on, if any: offset at the line's
/// minimum `lo` (every grid the bundle's encoder makes puts the minimum at q = 0) and `n ≤ 255`
/// steps up to its maximum `hi`. The full grid (`n = 255`) is tried first; a coarser one (a
/// floored step, or every k-th level) takes `n` from the smallest gap between the line's
/// distinct values, which is one step unless no two neighbouring levels are both used (then
/// the grid of that gap, if the values lie on it, serves as well). `sorted` is scratch.
fn line_grid(line: &[f32], lo: f32, hi: f32, sorted: &mut Vec<f32>) -> Option<(f32, f32)> {
    if hi <= lo {
        return Some((lo, 0.0));
    }
    let fits = |scale: f32| {
        line.iter().all(|&v| {
            let k = ((v - lo) / scale).round().clamp(0.0, 255.0);
            (lo + scale * k - v).abs() <= ON_GRID * scale
        })
    };
    let full = (hi - lo) / 255.0;
    if fits(full) {
        return Some((lo, full));
    }
    sorted.clear();
    sorted.extend_from_slice(line);
    sorted.sort_unstable_by(f32::total_cmp);
    let gap = sorted
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|&d| d > ON_GRID * full)
        .fold(f32::INFINITY, f32::min);
    let n = ((hi - lo) / gap).round();
    if !(1.0..255.0).contains(&n) {
        return None;
    }
    let scale = (hi - lo) / n;
    fits(scale).then_some((lo, scale))
}

/// Per-line `(offset, scale, q)` if every value of the lines lies on an 8-bit grid of its line
/// ([`line_grid`]).
fn on_u8_grid(
    data: &[f32],
    rows: usize,
    cols: usize,
    per_column: bool,
) -> Option<(Vec<f32>, Vec<f32>, Vec<u8>)> {
    let (lines, len) = if per_column {
        (cols, rows)
    } else {
        (rows, cols)
    };
    let at = |l: usize, k: usize| {
        if per_column {
            k * cols + l
        } else {
            l * cols + k
        }
    };
    let (mut offset, mut scale) = (Vec::with_capacity(lines), Vec::with_capacity(lines));
    let mut q = vec![0u8; rows * cols];
    let (mut line, mut sorted) = (Vec::with_capacity(len), Vec::new());
    for l in 0..lines {
        line.clear();
        line.extend((0..len).map(|k| data[at(l, k)]));
        let lo = line.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = line.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let (o, s) = line_grid(&line, lo, hi, &mut sorted)?;
        for (k, &v) in line.iter().enumerate() {
            if s > 0.0 {
                q[at(l, k)] = ((v - o) / s).round().clamp(0.0, 255.0) as u8;
            }
        }
        offset.push(o);
        scale.push(s);
    }
    Some((offset, scale, q))
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
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked above); the function has no other
            // contract.
            return unsafe { self.matvec_avx512(x, columns, scratch, emit) };
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked above); the function has no other contract.
            return unsafe { self.matvec_avx2(x, columns, scratch, emit) };
        }
        self.matvec_portable(x, columns, scratch, emit)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn matvec_avx512<E: FnMut(usize, [f32; 3])>(
        &self,
        x: [&[f32]; 3],
        columns: &[Range<usize>],
        scratch: &mut [f32],
        emit: E,
    ) {
        self.matvec_with::<Avx512, E>(x, columns, scratch, emit)
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
        self.matvec_with::<Avx2, E>(x, columns, scratch, emit)
    }

    fn matvec_portable<E: FnMut(usize, [f32; 3])>(
        &self,
        x: [&[f32]; 3],
        columns: &[Range<usize>],
        scratch: &mut [f32],
        emit: E,
    ) {
        self.matvec_with::<Portable, E>(x, columns, scratch, emit)
    }

    /// The product with the panel sums of `K`.
    #[inline(always)]
    fn matvec_with<K: PanelSum, E: FnMut(usize, [f32; 3])>(
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
        match &self.values {
            Values::F32(v) => {
                for (p, panel) in v.chunks_exact(cols * PANEL).enumerate() {
                    let acc = K::sum(panel, [x0, x1, x2], columns);
                    for lane in 0..PANEL.min(rows - p * PANEL) {
                        emit(p * PANEL + lane, [acc[0][lane], acc[1][lane], acc[2][lane]]);
                    }
                }
            }
            Values::U8Columns { q, offset, scale } => {
                // value = o_j + s_j q: Σ_j (o_j + s_j q_ij) x_j = Σ_j q_ij (s_j x_j) + Σ_j o_j x_j.
                let (xs, rest) = scratch[..3 * cols].split_at_mut(cols);
                let (ys, zs) = rest.split_at_mut(cols);
                let (mut c0, mut c1, mut c2) = (0.0f32, 0.0f32, 0.0f32);
                for r in columns {
                    let (s, o) = (&scale[r.clone()], &offset[r.clone()]);
                    let (a, b, c) = (&x0[r.clone()], &x1[r.clone()], &x2[r.clone()]);
                    for (out, x) in [(&mut *xs, a), (&mut *ys, b), (&mut *zs, c)] {
                        for ((out, &s), &x) in out[r.clone()].iter_mut().zip(s).zip(x) {
                            *out = s * x;
                        }
                    }
                    for (((&o, &a), &b), &c) in o.iter().zip(a).zip(b).zip(c) {
                        c0 += o * a;
                        c1 += o * b;
                        c2 += o * c;
                    }
                }
                let constant = [c0, c1, c2];
                for (p, panel) in q.chunks_exact(cols * PANEL).enumerate() {
                    let acc = K::sum(panel, [xs, ys, zs], columns);
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
                let (mut t0, mut t1, mut t2) = (0.0f32, 0.0f32, 0.0f32);
                for r in columns {
                    let (a, b, c) = (&x0[r.clone()], &x1[r.clone()], &x2[r.clone()]);
                    for ((&a, &b), &c) in a.iter().zip(b).zip(c) {
                        t0 += a;
                        t1 += b;
                        t2 += c;
                    }
                }
                let total = [t0, t1, t2];
                for (p, panel) in q.chunks_exact(cols * PANEL).enumerate() {
                    let acc = K::sum(panel, [x0, x1, x2], columns);
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

/// A stored value of a panel: f32, or an 8-bit grid index.
trait Lane: Copy {
    fn value(self) -> f32;

    /// The 16 values from `p` as f32.
    ///
    /// # Safety
    /// AVX-512F must be present and `p` must point at 16 readable values.
    #[cfg(target_arch = "x86_64")]
    unsafe fn load16(p: *const Self) -> std::arch::x86_64::__m512;

    /// The 8 values from `p` as f32.
    ///
    /// # Safety
    /// AVX2 must be present and `p` must point at 8 readable values.
    #[cfg(target_arch = "x86_64")]
    unsafe fn load8(p: *const Self) -> std::arch::x86_64::__m256;
}

impl Lane for f32 {
    #[inline(always)]
    fn value(self) -> f32 {
        self
    }

    #[cfg(target_arch = "x86_64")]
    #[inline]
    #[target_feature(enable = "avx512f")]
    unsafe fn load16(p: *const f32) -> std::arch::x86_64::__m512 {
        std::arch::x86_64::_mm512_loadu_ps(p)
    }

    #[cfg(target_arch = "x86_64")]
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn load8(p: *const f32) -> std::arch::x86_64::__m256 {
        std::arch::x86_64::_mm256_loadu_ps(p)
    }
}

impl Lane for u8 {
    #[inline(always)]
    fn value(self) -> f32 {
        self as f32
    }

    #[cfg(target_arch = "x86_64")]
    #[inline]
    #[target_feature(enable = "avx512f")]
    unsafe fn load16(p: *const u8) -> std::arch::x86_64::__m512 {
        use std::arch::x86_64::*;
        _mm512_cvtepi32_ps(_mm512_cvtepu8_epi32(_mm_loadu_si128(p.cast())))
    }

    #[cfg(target_arch = "x86_64")]
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn load8(p: *const u8) -> std::arch::x86_64::__m256 {
        use std::arch::x86_64::*;
        _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(p.cast())))
    }
}

/// `acc[c][lane] = Σ_j value(panel[j·PANEL + lane]) · x[c][j]` over the columns j of
/// `columns`, ascending: every lane multiplies, then adds, in column order, whichever
/// instruction set does it, so every implementation gives the same bits. A fused multiply-add
/// measured no faster on the maze's one-light update (its operators' part, eight interleaved
/// runs each: median 0.866 against 0.877 ms with 8-row AVX2 panels; 0.54–0.56 against
/// 0.54–0.56 ms with 16-row AVX-512 ones, three runs each) and would change every product's
/// bits.
trait PanelSum {
    fn sum<T: Lane>(panel: &[T], x: [&[f32]; 3], columns: &[Range<usize>]) -> [[f32; PANEL]; 3];
}

/// Any CPU.
struct Portable;

impl PanelSum for Portable {
    #[inline(always)]
    fn sum<T: Lane>(panel: &[T], x: [&[f32]; 3], columns: &[Range<usize>]) -> [[f32; PANEL]; 3] {
        let mut acc = [[0.0f32; PANEL]; 3];
        for r in columns {
            let panel = &panel[r.start * PANEL..r.end * PANEL];
            let [x0, x1, x2] = x.map(|x| &x[r.clone()]);
            for (((column, &a), &b), &c) in panel.chunks_exact(PANEL).zip(x0).zip(x1).zip(x2) {
                for lane in 0..PANEL {
                    let v = column[lane].value();
                    acc[0][lane] += v * a;
                    acc[1][lane] += v * b;
                    acc[2][lane] += v * c;
                }
            }
        }
        acc
    }
}

/// A panel in one AVX-512 register per channel.
#[cfg(target_arch = "x86_64")]
struct Avx512;

#[cfg(target_arch = "x86_64")]
impl PanelSum for Avx512 {
    #[inline(always)]
    fn sum<T: Lane>(panel: &[T], x: [&[f32]; 3], columns: &[Range<usize>]) -> [[f32; PANEL]; 3] {
        // SAFETY: only the AVX-512F copy of the product instantiates this kernel.
        unsafe { panel_sum_avx512(panel, x, columns) }
    }
}

/// [`PanelSum::sum`] in AVX-512 registers.
///
/// # Safety
/// AVX-512F must be present.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn panel_sum_avx512<T: Lane>(
    panel: &[T],
    x: [&[f32]; 3],
    columns: &[Range<usize>],
) -> [[f32; PANEL]; 3] {
    use std::arch::x86_64::*;
    let (mut a0, mut a1, mut a2) = (
        _mm512_setzero_ps(),
        _mm512_setzero_ps(),
        _mm512_setzero_ps(),
    );
    for r in columns {
        let panel = &panel[r.start * PANEL..r.end * PANEL];
        let [x0, x1, x2] = x.map(|x| &x[r.clone()]);
        for (((column, &a), &b), &c) in panel.chunks_exact(PANEL).zip(x0).zip(x1).zip(x2) {
            // SAFETY: `column` holds PANEL = 16 values.
            let v = T::load16(column.as_ptr());
            a0 = _mm512_add_ps(a0, _mm512_mul_ps(v, _mm512_set1_ps(a)));
            a1 = _mm512_add_ps(a1, _mm512_mul_ps(v, _mm512_set1_ps(b)));
            a2 = _mm512_add_ps(a2, _mm512_mul_ps(v, _mm512_set1_ps(c)));
        }
    }
    let mut acc = [[0.0f32; PANEL]; 3];
    _mm512_storeu_ps(acc[0].as_mut_ptr(), a0);
    _mm512_storeu_ps(acc[1].as_mut_ptr(), a1);
    _mm512_storeu_ps(acc[2].as_mut_ptr(), a2);
    acc
}

/// A panel in two AVX2 registers per channel.
#[cfg(target_arch = "x86_64")]
struct Avx2;

#[cfg(target_arch = "x86_64")]
impl PanelSum for Avx2 {
    #[inline(always)]
    fn sum<T: Lane>(panel: &[T], x: [&[f32]; 3], columns: &[Range<usize>]) -> [[f32; PANEL]; 3] {
        // SAFETY: only the AVX2 copy of the product instantiates this kernel.
        unsafe { panel_sum_avx2(panel, x, columns) }
    }
}

/// [`PanelSum::sum`] in AVX2 registers.
///
/// # Safety
/// AVX2 must be present.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn panel_sum_avx2<T: Lane>(
    panel: &[T],
    x: [&[f32]; 3],
    columns: &[Range<usize>],
) -> [[f32; PANEL]; 3] {
    use std::arch::x86_64::*;
    let mut a = [_mm256_setzero_ps(); 6];
    for r in columns {
        let panel = &panel[r.start * PANEL..r.end * PANEL];
        let [x0, x1, x2] = x.map(|x| &x[r.clone()]);
        for (((column, &p), &q), &s) in panel.chunks_exact(PANEL).zip(x0).zip(x1).zip(x2) {
            // SAFETY: `column` holds PANEL = 16 values.
            let lo = T::load8(column.as_ptr());
            let hi = T::load8(column.as_ptr().add(8));
            let (p, q, s) = (_mm256_set1_ps(p), _mm256_set1_ps(q), _mm256_set1_ps(s));
            a[0] = _mm256_add_ps(a[0], _mm256_mul_ps(lo, p));
            a[1] = _mm256_add_ps(a[1], _mm256_mul_ps(hi, p));
            a[2] = _mm256_add_ps(a[2], _mm256_mul_ps(lo, q));
            a[3] = _mm256_add_ps(a[3], _mm256_mul_ps(hi, q));
            a[4] = _mm256_add_ps(a[4], _mm256_mul_ps(lo, s));
            a[5] = _mm256_add_ps(a[5], _mm256_mul_ps(hi, s));
        }
    }
    let mut acc = [[0.0f32; PANEL]; 3];
    for (c, acc) in acc.iter_mut().enumerate() {
        _mm256_storeu_ps(acc.as_mut_ptr(), a[2 * c]);
        _mm256_storeu_ps(acc.as_mut_ptr().add(8), a[2 * c + 1]);
    }
    acc
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::codec::{round_trip, round_trip_grid, MatrixCodec, U8Grid};

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

    /// The AVX-512, AVX2 and portable builds give the same bits (each one the CPU has), on a
    /// matrix with a partial last panel and runs of columns.
    #[test]
    fn dispatch_is_bit_identical() {
        let m = matrix(37, 29, 3);
        let x: Vec<Vec<f32>> = (0..3).map(|c| matrix(1, 29, 11 + c).data).collect();
        let x = [&x[0][..], &x[1][..], &x[2][..]];
        let (every, runs) = (0..29, [1..4, 6..20]);
        for columns in [std::slice::from_ref(&every), &runs[..]] {
            for (_, p, mut scratch) in in_every_storage(&m) {
                let mut portable = Vec::new();
                p.matvec_portable(x, columns, &mut scratch, |_, v| portable.push(v));
                let mut dispatched = Vec::new();
                p.matvec_columns(x, columns, &mut scratch, |_, v| dispatched.push(v));
                assert_eq!(dispatched, portable);
                #[cfg(target_arch = "x86_64")]
                {
                    let mut simd = Vec::new();
                    if std::arch::is_x86_feature_detected!("avx2") {
                        // SAFETY: the CPU supports AVX2.
                        unsafe { p.matvec_avx2(x, columns, &mut scratch, |_, v| simd.push(v)) };
                        assert_eq!(simd, portable, "AVX2");
                    }
                    simd.clear();
                    if std::arch::is_x86_feature_detected!("avx512f") {
                        // SAFETY: the CPU supports AVX-512F.
                        unsafe { p.matvec_avx512(x, columns, &mut scratch, |_, v| simd.push(v)) };
                        assert_eq!(simd, portable, "AVX-512");
                    }
                }
            }
        }
    }

    /// The encoder's other 8-bit grids — one floor on the lines' steps (lines narrower than
    /// 255 floors take fewer levels, and their minimum is not a multiple of the floor) and
    /// every k-th level — decode to values the packing still keeps in 8 bits, with products
    /// as exact as the full grid's.
    #[test]
    fn floored_and_coarser_grids_stay_8_bit() {
        let (rows, cols) = (40, 24);
        let mut m = matrix(rows, cols, 17);
        // Lines of very different ranges: column j (and row i) scaled by up to 10^±2.
        for i in 0..rows {
            for j in 0..cols {
                let k = (i % 5) as i32 - 2 + (j % 3) as i32 - 1;
                m.data[i * cols + j] *= 10f32.powi(k);
            }
        }
        let x: Vec<Vec<f32>> = (0..3).map(|c| matrix(1, cols, 31 + c).data).collect();
        let x = [&x[0][..], &x[1][..], &x[2][..]];
        for codec in [MatrixCodec::U8Columns, MatrixCodec::U8Rows] {
            for grid in [U8Grid::Floor(1e-3), U8Grid::Floor(0.05), U8Grid::Step(5)] {
                let decoded = Matrix {
                    data: round_trip_grid(&m.data, rows, cols, codec, grid),
                    ..m.clone()
                };
                let packed = PackedMatrix::new(&decoded);
                assert!(packed.is_u8(), "{codec:?} on {grid:?} kept in 8 bits");
                let want = reference(&decoded, x);
                // f32 sums of `offset + scale · q` terms: within a few roundings of the sum
                // of |x_j| times the largest value of the line (row or column) a term is on.
                let line_max = |i: usize, j: usize| {
                    let column = (0..rows).map(|k| decoded.data[k * cols + j].abs());
                    let row = (0..cols).map(|k| decoded.data[i * cols + k].abs());
                    column.chain(row).fold(0.0f32, f32::max) as f64
                };
                let size: Vec<[f64; 3]> = (0..rows)
                    .map(|i| {
                        [0, 1, 2].map(|c| {
                            (0..cols)
                                .map(|j| line_max(i, j) * x[c][j].abs() as f64)
                                .sum()
                        })
                    })
                    .collect();
                for ((g, w), size) in product(&packed, x).iter().zip(&want).zip(&size) {
                    for c in 0..3 {
                        let tol = 4.0 * cols as f64 * f32::EPSILON as f64 * size[c];
                        assert!(
                            (g[c] as f64 - w[c]).abs() < tol,
                            "{codec:?} {grid:?}: {} vs {}",
                            g[c],
                            w[c]
                        );
                    }
                }
            }
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
