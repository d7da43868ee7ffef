//! The per-frame runtime: direct light in, indirect light out, by the bundle's operators.
//!
//! Owns the decoded [`Bundle`] and every scratch buffer the per-frame work needs, so
//! [`Runtime::apply`] allocates nothing (it only resizes `out` when its length is wrong).
//!
//! [`Method::Mrt`] (modular radiance transfer), for every block B and channel c:
//! 1. `b_B = T_d→b · l_d^B` (l_d^B: the block's texel range of direct radiance);
//! 2. `l_ind^B = U_b · b_B`;
//! 3. transport: Traced adds `M · b_A` for every entry (target B, source A); Lightfield sums
//!    `r_(B,face) = Σ M · b_A` over the entries into each opening, then adds `U_r · r_(B,face)`
//!    with the shape's (first) opening of that face;
//! 4. multiplies by the receiving texel's albedo. Texels in no block (clutter) get 0.
//!
//! [`Method::Full`]: `l_ind = ρ ⊙ (F · l_d)` with the bundle's sparse dense-bounce operator F.
//!
//! Invariants:
//! - A [`Runtime`] only exists for a bundle whose sizes and indices are consistent (checked in
//!   [`Runtime::try_new`]; always true of a bundle from `Bundle::decode`), so `apply` indexes
//!   without further checks and its only errors are the ones in [`ApplyError`].
//! - `apply` is deterministic: the same direct light gives bit-identical output every call.
//! - Scratch vectors are planar (channel-major: channel c of an n-vector at `c·n .. (c+1)·n`),
//!   so every matrix row is one contiguous pass accumulating all three channels.

use lightfarm_proto::bundle::{Bundle, BundleError, Matrix, TransportOps};

use crate::direct::DirectLight;

/// Which operator turns direct into indirect light.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Method {
    /// The sparse dense-bounce operator over all texels (the bundle's `full`, if baked).
    Full,
    /// Modular radiance transfer: per-block operators plus inter-block transport.
    Mrt,
}

/// Indirect outgoing radiance, one RGB value per layout texel.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IndirectLight {
    pub radiance: Vec<[f32; 3]>,
}

/// Why [`Runtime::apply`] could not run.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ApplyError {
    #[error("this bundle has no dense operator; bake it with --full")]
    MissingFull,
    #[error("direct light has {got} texels but the bundle's layout has {expected}")]
    DirectLength { expected: usize, got: usize },
}

/// Reduced incoming lightfield of one opening of one block.
#[derive(Clone, Copy, Debug)]
struct Slot {
    block: usize,
    opening: usize,
    /// Offset of its q coefficients in the lightfield scratch.
    offset: usize,
    /// Whether any transport entry feeds it (unfed slots are skipped).
    fed: bool,
}

/// Decoded bundle plus scratch, ready to apply every frame.
#[derive(Clone, Debug)]
pub struct Runtime {
    bundle: Bundle,
    n_texels: usize,
    /// Per block: offset of its r coefficients in `b`.
    coef_offset: Vec<usize>,
    /// Total coefficients over all blocks.
    n_coef: usize,
    /// Per (block, opening) of the lightfield transport, block-major.
    slots: Vec<Slot>,
    /// Per lightfield transport entry: its slot.
    entry_slot: Vec<usize>,
    /// Total lightfield coefficients over all slots.
    n_lf: usize,
    /// Scratch: direct radiance, planar, 3 × n_texels.
    ld: Vec<f32>,
    /// Scratch: block coefficients, planar, 3 × n_coef.
    b: Vec<f32>,
    /// Scratch: reduced lightfield coefficients, planar, 3 × n_lf.
    lf: Vec<f32>,
}

/// Row · x for three channels in one pass; `x[c]` must be at least as long as `row`.
///
/// Eight independent partial sums per channel let the compiler keep them in vector registers
/// (floating-point addition is not reassociated for us). The summation order is fixed, so the
/// result is deterministic.
#[inline]
fn dot3(row: &[f32], x: [&[f32]; 3]) -> [f32; 3] {
    const LANES: usize = 8;
    let n = row.len();
    let (x0, x1, x2) = (&x[0][..n], &x[1][..n], &x[2][..n]);
    let body = n - n % LANES;
    let mut acc = [[0.0f32; LANES]; 3];
    for (((r, a), b), c) in row[..body]
        .chunks_exact(LANES)
        .zip(x0[..body].chunks_exact(LANES))
        .zip(x1[..body].chunks_exact(LANES))
        .zip(x2[..body].chunks_exact(LANES))
    {
        for k in 0..LANES {
            acc[0][k] += r[k] * a[k];
            acc[1][k] += r[k] * b[k];
            acc[2][k] += r[k] * c[k];
        }
    }
    let mut s = [0.0f32; 3];
    for k in body..n {
        s[0] += row[k] * x0[k];
        s[1] += row[k] * x1[k];
        s[2] += row[k] * x2[k];
    }
    for (sc, ac) in s.iter_mut().zip(&acc) {
        *sc += ac.iter().sum::<f32>();
    }
    s
}

/// The three channel slices `[offset, offset + len)` of a planar 3 × `stride` vector.
#[inline]
fn planar(v: &[f32], stride: usize, offset: usize, len: usize) -> [&[f32]; 3] {
    [
        &v[offset..offset + len],
        &v[stride + offset..stride + offset + len],
        &v[2 * stride + offset..2 * stride + offset + len],
    ]
}

/// `out[t] += M · x` for every row t of `m`.
#[inline]
fn add_matvec(out: &mut [[f32; 3]], m: &Matrix, x: [&[f32]; 3]) {
    let cols = m.cols as usize;
    if cols == 0 {
        return;
    }
    for (o, row) in out.iter_mut().zip(m.data.chunks_exact(cols)) {
        let v = dot3(row, x);
        o[0] += v[0];
        o[1] += v[1];
        o[2] += v[2];
    }
}

fn check_matrix(m: &Matrix, rows: u32, cols: u32, what: &str) -> Result<(), BundleError> {
    if m.rows != rows || m.cols != cols || m.data.len() as u64 != rows as u64 * cols as u64 {
        return Err(BundleError::Invalid(format!(
            "{what}: {}×{} matrix with {} values, expected {rows}×{cols}",
            m.rows,
            m.cols,
            m.data.len()
        )));
    }
    Ok(())
}

/// Checks every size and index the runtime relies on: the subset of `Bundle::decode`'s
/// validation that matters here, for bundles built by hand.
fn check(bundle: &Bundle) -> Result<(), BundleError> {
    let bad = |m: String| Err(BundleError::Invalid(m));
    let layout = &bundle.layout;
    let n_texels = layout.n_texels() as u64;
    if layout.normals.len() as u64 != n_texels || layout.albedo.len() as u64 != n_texels {
        return bad("layout: positions, normals and albedo differ in length".into());
    }
    for (k, s) in bundle.shapes.iter().enumerate() {
        check_matrix(&s.u_b, s.u_b.rows, s.u_b.cols, &format!("shape {k} U_b"))?;
        check_matrix(&s.t_db, s.u_b.cols, s.u_b.rows, &format!("shape {k} T_d→b"))?;
        for o in &s.openings {
            if o.face > 5 {
                return bad(format!("shape {k}: opening face {} out of range", o.face));
            }
            check_matrix(&o.u_r, s.u_b.rows, o.u_r.cols, &format!("shape {k} U_r"))?;
        }
    }
    for b in &bundle.blocks {
        let Some(shape) = bundle.shapes.get(b.shape as usize) else {
            return bad(format!("block {}: shape {} does not exist", b.id, b.shape));
        };
        if b.texel_offset as u64 + shape.u_b.rows as u64 > n_texels {
            return bad(format!("block {}: texel range past the layout", b.id));
        }
    }
    let shape_of = |i: u32| {
        bundle
            .blocks
            .get(i as usize)
            .map(|b| &bundle.shapes[b.shape as usize])
    };
    match &bundle.transport {
        Some(TransportOps::Lightfield(entries)) => {
            for e in entries {
                let (Some(target), Some(source)) =
                    (shape_of(e.target_block), shape_of(e.source_block))
                else {
                    return bad("transport: entry names a missing block".into());
                };
                let Some(opening) = target.openings.iter().find(|o| o.face == e.target_face) else {
                    return bad("transport: entry names an opening the shape lacks".into());
                };
                check_matrix(&e.matrix, opening.u_r.cols, source.u_b.cols, "transport")?;
            }
        }
        Some(TransportOps::Traced(entries)) => {
            for e in entries {
                let (Some(target), Some(source)) =
                    (shape_of(e.target_block), shape_of(e.source_block))
                else {
                    return bad("transport: entry names a missing block".into());
                };
                check_matrix(&e.matrix, target.u_b.rows, source.u_b.cols, "transport")?;
            }
        }
        None => {}
    }
    if let Some(f) = &bundle.full {
        if f.n as u64 != n_texels || f.row_start.len() as u64 != n_texels + 1 {
            return bad("full: size does not match the layout".into());
        }
        if f.row_start.first() != Some(&0)
            || f.row_start.windows(2).any(|w| w[1] < w[0])
            || f.row_start.last().map(|&l| l as usize) != Some(f.cols.len())
            || f.cols.len() != f.values.len()
        {
            return bad("full: row starts are inconsistent".into());
        }
        if f.cols.iter().any(|&c| c >= f.n) {
            return bad("full: column index out of range".into());
        }
    }
    Ok(())
}

impl Runtime {
    /// Takes the bundle and sizes every scratch buffer.
    ///
    /// # Panics
    /// If the bundle is inconsistent (see [`Runtime::try_new`]); never for a bundle returned by
    /// `Bundle::decode`.
    pub fn new(bundle: Bundle) -> Runtime {
        match Runtime::try_new(bundle) {
            Ok(rt) => rt,
            Err(e) => panic!("inconsistent bundle: {e}"),
        }
    }

    /// Like [`Runtime::new`], but refuses a bundle whose sizes or indices are inconsistent
    /// (possible only for a bundle built by hand).
    pub fn try_new(bundle: Bundle) -> Result<Runtime, BundleError> {
        check(&bundle)?;
        let n_texels = bundle.layout.n_texels();
        let mut coef_offset = Vec::with_capacity(bundle.blocks.len());
        let mut n_coef = 0;
        for b in &bundle.blocks {
            coef_offset.push(n_coef);
            n_coef += bundle.shapes[b.shape as usize].u_b.cols as usize;
        }

        let (mut slots, mut entry_slot, mut n_lf) = (Vec::new(), Vec::new(), 0);
        if let Some(TransportOps::Lightfield(entries)) = &bundle.transport {
            // First slot of every block; a block has one slot per opening of its shape.
            let mut first_slot = Vec::with_capacity(bundle.blocks.len());
            for (bi, b) in bundle.blocks.iter().enumerate() {
                first_slot.push(slots.len());
                for (oi, o) in bundle.shapes[b.shape as usize].openings.iter().enumerate() {
                    slots.push(Slot {
                        block: bi,
                        opening: oi,
                        offset: n_lf,
                        fed: false,
                    });
                    n_lf += o.u_r.cols as usize;
                }
            }
            for e in entries {
                let target = &bundle.blocks[e.target_block as usize];
                let openings = &bundle.shapes[target.shape as usize].openings;
                // `check` guarantees the opening exists.
                let oi = openings
                    .iter()
                    .position(|o| o.face == e.target_face)
                    .unwrap_or(0);
                let s = first_slot[e.target_block as usize] + oi;
                slots[s].fed = true;
                entry_slot.push(s);
            }
        }

        Ok(Runtime {
            n_texels,
            coef_offset,
            n_coef,
            slots,
            entry_slot,
            n_lf,
            ld: vec![0.0; 3 * n_texels],
            b: vec![0.0; 3 * n_coef],
            lf: vec![0.0; 3 * n_lf],
            bundle,
        })
    }

    /// The bundle this runtime applies.
    pub fn bundle(&self) -> &Bundle {
        &self.bundle
    }

    /// Number of layout texels (the length of the direct and indirect vectors).
    pub fn n_texels(&self) -> usize {
        self.n_texels
    }

    /// Whether [`Method::Full`] is available (the bundle was baked with `--full`).
    pub fn has_full(&self) -> bool {
        self.bundle.full.is_some()
    }

    /// Turns direct light into indirect light by `method`, writing every texel of `out`
    /// (resized to the texel count if its length is wrong; otherwise no allocation).
    pub fn apply(
        &mut self,
        method: Method,
        direct: &DirectLight,
        out: &mut IndirectLight,
    ) -> Result<(), ApplyError> {
        let n = self.n_texels;
        if direct.radiance.len() != n {
            return Err(ApplyError::DirectLength {
                expected: n,
                got: direct.radiance.len(),
            });
        }
        if method == Method::Full && self.bundle.full.is_none() {
            return Err(ApplyError::MissingFull);
        }
        if out.radiance.len() != n {
            out.radiance.clear();
            out.radiance.resize(n, [0.0; 3]);
        }
        match method {
            Method::Full => self.apply_full(&direct.radiance, &mut out.radiance),
            Method::Mrt => self.apply_mrt(&direct.radiance, &mut out.radiance),
        }
        Ok(())
    }

    fn apply_full(&self, direct: &[[f32; 3]], out: &mut [[f32; 3]]) {
        let Some(f) = &self.bundle.full else { return };
        let albedo = &self.bundle.layout.albedo;
        for ((o, rho), w) in out.iter_mut().zip(albedo).zip(f.row_start.windows(2)) {
            let (start, end) = (w[0] as usize, w[1] as usize);
            let mut s = [0.0f32; 3];
            for (&c, &v) in f.cols[start..end].iter().zip(&f.values[start..end]) {
                let l = direct[c as usize];
                s[0] += v * l[0];
                s[1] += v * l[1];
                s[2] += v * l[2];
            }
            *o = [rho[0] * s[0], rho[1] * s[1], rho[2] * s[2]];
        }
    }

    fn apply_mrt(&mut self, direct: &[[f32; 3]], out: &mut [[f32; 3]]) {
        let n = self.n_texels;
        let Runtime {
            bundle,
            coef_offset,
            n_coef,
            slots,
            entry_slot,
            n_lf,
            ld,
            b,
            lf,
            ..
        } = self;
        let (n_coef, n_lf) = (*n_coef, *n_lf);

        // Direct light, planar.
        let (ld0, rest) = ld.split_at_mut(n);
        let (ld1, ld2) = rest.split_at_mut(n);
        for (((l, a), bb), c) in direct.iter().zip(ld0).zip(ld1).zip(ld2) {
            (*a, *bb, *c) = (l[0], l[1], l[2]);
        }

        // 1. b_B = T_d→b · l_d^B.
        for (blk, &co) in bundle.blocks.iter().zip(coef_offset.iter()) {
            let shape = &bundle.shapes[blk.shape as usize];
            let texels = shape.u_b.rows as usize;
            let x = planar(ld, n, blk.texel_offset as usize, texels);
            if texels == 0 {
                b[co..co + shape.t_db.rows as usize].fill(0.0);
                b[n_coef + co..n_coef + co + shape.t_db.rows as usize].fill(0.0);
                b[2 * n_coef + co..2 * n_coef + co + shape.t_db.rows as usize].fill(0.0);
                continue;
            }
            for (j, row) in shape.t_db.data.chunks_exact(texels).enumerate() {
                let v = dot3(row, x);
                b[co + j] = v[0];
                b[n_coef + co + j] = v[1];
                b[2 * n_coef + co + j] = v[2];
            }
        }

        // 2. l_ind^B = U_b · b_B (clutter texels stay 0).
        out.fill([0.0; 3]);
        for (blk, &co) in bundle.blocks.iter().zip(coef_offset.iter()) {
            let shape = &bundle.shapes[blk.shape as usize];
            let off = blk.texel_offset as usize;
            let texels = shape.u_b.rows as usize;
            add_matvec(
                &mut out[off..off + texels],
                &shape.u_b,
                planar(b, n_coef, co, shape.u_b.cols as usize),
            );
        }

        // 3. Inter-block transport.
        match &bundle.transport {
            Some(TransportOps::Traced(entries)) => {
                for e in entries {
                    let target = &bundle.blocks[e.target_block as usize];
                    let off = target.texel_offset as usize;
                    let rows = e.matrix.rows as usize;
                    let co = coef_offset[e.source_block as usize];
                    add_matvec(
                        &mut out[off..off + rows],
                        &e.matrix,
                        planar(b, n_coef, co, e.matrix.cols as usize),
                    );
                }
            }
            Some(TransportOps::Lightfield(entries)) => {
                lf.fill(0.0);
                for (e, &s) in entries.iter().zip(entry_slot.iter()) {
                    let lo = slots[s].offset;
                    let co = coef_offset[e.source_block as usize];
                    let cols = e.matrix.cols as usize;
                    if cols == 0 {
                        continue;
                    }
                    let x = planar(b, n_coef, co, cols);
                    for (j, row) in e.matrix.data.chunks_exact(cols).enumerate() {
                        let v = dot3(row, x);
                        lf[lo + j] += v[0];
                        lf[n_lf + lo + j] += v[1];
                        lf[2 * n_lf + lo + j] += v[2];
                    }
                }
                for slot in slots.iter().filter(|s| s.fed) {
                    let blk = &bundle.blocks[slot.block];
                    let u_r = &bundle.shapes[blk.shape as usize].openings[slot.opening].u_r;
                    let off = blk.texel_offset as usize;
                    let texels = u_r.rows as usize;
                    add_matvec(
                        &mut out[off..off + texels],
                        u_r,
                        planar(lf, n_lf, slot.offset, u_r.cols as usize),
                    );
                }
            }
            None => {}
        }

        // 4. Albedo of the receiving texel.
        for (o, rho) in out.iter_mut().zip(&bundle.layout.albedo) {
            o[0] *= rho[0];
            o[1] *= rho[1];
            o[2] *= rho[2];
        }
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use crate::occluders::tests::Lcg;
    use lightfarm_proto::bundle::{
        BlockOps, Layout, OpeningOps, PropEntry, ShapeOps, SparseRows, SurfaceInfo, TracedEntry,
    };
    use std::alloc::{GlobalAlloc, Layout as AllocLayout, System};
    use std::cell::Cell;

    /// Counts allocations made by the current thread (tests run on separate threads).
    struct CountingAlloc;

    thread_local! {
        static ALLOCS: Cell<u64> = const { Cell::new(0) };
    }

    unsafe impl GlobalAlloc for CountingAlloc {
        unsafe fn alloc(&self, layout: AllocLayout) -> *mut u8 {
            let _ = ALLOCS.try_with(|a| a.set(a.get() + 1));
            unsafe { System.alloc(layout) }
        }
        unsafe fn dealloc(&self, ptr: *mut u8, layout: AllocLayout) {
            unsafe { System.dealloc(ptr, layout) }
        }
        unsafe fn realloc(&self, ptr: *mut u8, layout: AllocLayout, new_size: usize) -> *mut u8 {
            let _ = ALLOCS.try_with(|a| a.set(a.get() + 1));
            unsafe { System.realloc(ptr, layout, new_size) }
        }
    }

    #[global_allocator]
    static GLOBAL: CountingAlloc = CountingAlloc;

    fn allocs() -> u64 {
        ALLOCS.with(|a| a.get())
    }

    fn matrix(rng: &mut Lcg, rows: usize, cols: usize) -> Matrix {
        Matrix {
            rows: rows as u32,
            cols: cols as u32,
            data: (0..rows * cols).map(|_| rng.range(-1.0, 1.0)).collect(),
        }
    }

    /// Three blocks (shape 0: 4 texels, r = 2, openings +x (q = 3) and -z (q = 2); shape 1:
    /// 11 texels, r = 3, opening -x (q = 2)), then 2 clutter texels.
    fn bundle(rng: &mut Lcg, transport: Option<TransportOps>, full: bool) -> Bundle {
        let texels = [4usize, 11, 4];
        let offsets = [0usize, 4, 15];
        let n = 21;
        let mut surfaces: Vec<SurfaceInfo> = ["block:a/+x", "block:b/-x", "block:c/+x"]
            .iter()
            .zip(texels.iter().zip(offsets))
            .map(|(name, (&count, off))| SurfaceInfo {
                name: (*name).into(),
                texel_offset: off as u32,
                texel_count: count as u32,
            })
            .collect();
        surfaces.push(SurfaceInfo {
            name: "clutter:box".into(),
            texel_offset: 19,
            texel_count: 2,
        });
        let layout = Layout {
            scene_name: "hand-built".into(),
            surfaces,
            positions: (0..n).map(|i| [i as f32, 0.0, 0.0]).collect(),
            normals: vec![[0.0, 0.0, 1.0]; n],
            texel_size: vec![[0.5, 0.5]; n],
            albedo: (0..n)
                .map(|_| {
                    [
                        rng.range(0.1, 0.9),
                        rng.range(0.1, 0.9),
                        rng.range(0.1, 0.9),
                    ]
                })
                .collect(),
            rects: vec![],
            triangles: vec![],
        };
        let shapes = vec![
            ShapeOps {
                key: "s0".into(),
                u_b: matrix(rng, 4, 2),
                t_db: matrix(rng, 2, 4),
                openings: vec![
                    OpeningOps {
                        face: 1,
                        u_r: matrix(rng, 4, 3),
                    },
                    OpeningOps {
                        face: 4,
                        u_r: matrix(rng, 4, 2),
                    },
                ],
            },
            ShapeOps {
                key: "s1".into(),
                u_b: matrix(rng, 11, 3),
                t_db: matrix(rng, 3, 11),
                openings: vec![OpeningOps {
                    face: 0,
                    u_r: matrix(rng, 11, 2),
                }],
            },
        ];
        let blocks = vec![
            BlockOps {
                id: "a".into(),
                shape: 0,
                texel_offset: 0,
            },
            BlockOps {
                id: "b".into(),
                shape: 1,
                texel_offset: 4,
            },
            BlockOps {
                id: "c".into(),
                shape: 0,
                texel_offset: 15,
            },
        ];
        let full = full.then(|| {
            let mut f = SparseRows {
                n: n as u32,
                row_start: vec![0],
                cols: vec![],
                values: vec![],
            };
            for _ in 0..n {
                for c in 0..n as u32 {
                    if rng.next_u32().is_multiple_of(3) {
                        f.cols.push(c);
                        f.values.push(rng.range(0.0, 0.1));
                    }
                }
                f.row_start.push(f.cols.len() as u32);
            }
            f
        });
        Bundle {
            layout,
            shapes,
            blocks,
            transport,
            full,
            drt: None,
        }
    }

    /// Coefficient counts r and opening sizes q by block, as the test bundle has them.
    const R: [usize; 3] = [2, 3, 2];

    fn traced(rng: &mut Lcg) -> TransportOps {
        let texels = [4usize, 11, 4];
        let pairs = [(1u32, 0u32), (0, 2), (0, 1), (2, 2), (0, 2)];
        TransportOps::Traced(
            pairs
                .iter()
                .map(|&(t, s)| TracedEntry {
                    target_block: t,
                    source_block: s,
                    matrix: matrix(rng, texels[t as usize], R[s as usize]),
                })
                .collect(),
        )
    }

    fn lightfield(rng: &mut Lcg) -> TransportOps {
        // (target, face, q, source); two entries feed block a's +x opening.
        let entries = [
            (0u32, 1u8, 3usize, 1u32),
            (0, 4, 2, 2),
            (0, 1, 3, 2),
            (1, 0, 2, 0),
            (2, 1, 3, 0),
        ];
        TransportOps::Lightfield(
            entries
                .iter()
                .map(|&(t, face, q, s)| PropEntry {
                    target_block: t,
                    target_face: face,
                    source_block: s,
                    matrix: matrix(rng, q, R[s as usize]),
                })
                .collect(),
        )
    }

    fn direct(rng: &mut Lcg, n: usize) -> DirectLight {
        DirectLight {
            radiance: (0..n)
                .map(|_| {
                    [
                        rng.range(0.0, 2.0),
                        rng.range(0.0, 2.0),
                        rng.range(0.0, 2.0),
                    ]
                })
                .collect(),
        }
    }

    fn get(m: &Matrix, i: usize, j: usize) -> f64 {
        m.data[i * m.cols as usize + j] as f64
    }

    /// Straightforward dense MRT, in f64.
    fn reference_mrt(bundle: &Bundle, ld: &[[f32; 3]]) -> Vec<[f64; 3]> {
        let shape = |bi: u32| &bundle.shapes[bundle.blocks[bi as usize].shape as usize];
        let coefs: Vec<Vec<[f64; 3]>> = bundle
            .blocks
            .iter()
            .map(|blk| {
                let s = &bundle.shapes[blk.shape as usize];
                (0..s.t_db.rows as usize)
                    .map(|j| {
                        let mut v = [0.0; 3];
                        for t in 0..s.t_db.cols as usize {
                            for c in 0..3 {
                                v[c] += get(&s.t_db, j, t)
                                    * ld[blk.texel_offset as usize + t][c] as f64;
                            }
                        }
                        v
                    })
                    .collect()
            })
            .collect();
        let mut out = vec![[0.0f64; 3]; ld.len()];
        let mut add = |bi: u32, m: &Matrix, x: &[[f64; 3]]| {
            let off = bundle.blocks[bi as usize].texel_offset as usize;
            for t in 0..m.rows as usize {
                for j in 0..m.cols as usize {
                    for c in 0..3 {
                        out[off + t][c] += get(m, t, j) * x[j][c];
                    }
                }
            }
        };
        for (bi, x) in coefs.iter().enumerate() {
            add(bi as u32, &shape(bi as u32).u_b, x);
        }
        match &bundle.transport {
            Some(TransportOps::Traced(entries)) => {
                for e in entries {
                    add(e.target_block, &e.matrix, &coefs[e.source_block as usize]);
                }
            }
            Some(TransportOps::Lightfield(entries)) => {
                for (bi, _) in bundle.blocks.iter().enumerate() {
                    for o in &shape(bi as u32).openings {
                        let mut r = vec![[0.0f64; 3]; o.u_r.cols as usize];
                        for e in entries
                            .iter()
                            .filter(|e| e.target_block == bi as u32 && e.target_face == o.face)
                        {
                            for (k, rk) in r.iter_mut().enumerate() {
                                for j in 0..e.matrix.cols as usize {
                                    for c in 0..3 {
                                        rk[c] += get(&e.matrix, k, j)
                                            * coefs[e.source_block as usize][j][c];
                                    }
                                }
                            }
                        }
                        add(bi as u32, &o.u_r, &r);
                    }
                }
            }
            None => {}
        }
        for (o, rho) in out.iter_mut().zip(&bundle.layout.albedo) {
            for c in 0..3 {
                o[c] *= rho[c] as f64;
            }
        }
        out
    }

    fn reference_full(bundle: &Bundle, ld: &[[f32; 3]]) -> Vec<[f64; 3]> {
        let f = bundle.full.as_ref().unwrap();
        (0..f.n as usize)
            .map(|i| {
                let mut v = [0.0f64; 3];
                for k in f.row_start[i] as usize..f.row_start[i + 1] as usize {
                    for c in 0..3 {
                        v[c] += f.values[k] as f64 * ld[f.cols[k] as usize][c] as f64;
                    }
                }
                for c in 0..3 {
                    v[c] *= bundle.layout.albedo[i][c] as f64;
                }
                v
            })
            .collect()
    }

    fn assert_close(got: &IndirectLight, want: &[[f64; 3]]) {
        assert_eq!(got.radiance.len(), want.len());
        for (i, (g, w)) in got.radiance.iter().zip(want).enumerate() {
            for c in 0..3 {
                assert!(
                    (g[c] as f64 - w[c]).abs() <= 1e-5 * (1.0 + w[c].abs()),
                    "texel {i} channel {c}: {} vs {}",
                    g[c],
                    w[c]
                );
            }
        }
    }

    fn run(bundle: Bundle, method: Method, ld: &DirectLight) -> IndirectLight {
        let mut rt = Runtime::new(bundle);
        let mut out = IndirectLight::default();
        rt.apply(method, ld, &mut out).unwrap();
        out
    }

    #[test]
    fn dot3_matches_a_plain_loop_at_every_length() {
        let mut rng = Lcg(3);
        for n in 0..40 {
            let row: Vec<f32> = (0..n).map(|_| rng.range(-1.0, 1.0)).collect();
            let x: Vec<Vec<f32>> = (0..3)
                .map(|_| (0..n).map(|_| rng.range(-1.0, 1.0)).collect())
                .collect();
            let got = dot3(&row, [&x[0], &x[1], &x[2]]);
            for c in 0..3 {
                let want: f64 = row
                    .iter()
                    .zip(&x[c])
                    .map(|(a, b)| *a as f64 * *b as f64)
                    .sum();
                assert!((got[c] as f64 - want).abs() < 1e-5, "n = {n}");
            }
        }
    }

    #[test]
    fn mrt_with_traced_transport_matches_reference() {
        let mut rng = Lcg(11);
        let t = traced(&mut rng);
        let b = bundle(&mut rng, Some(t), false);
        let ld = direct(&mut rng, 21);
        let want = reference_mrt(&b, &ld.radiance);
        let got = run(b, Method::Mrt, &ld);
        assert_close(&got, &want);
        assert_eq!(
            &got.radiance[19..],
            &[[0.0; 3]; 2],
            "clutter texels get 0 under MRT"
        );
    }

    #[test]
    fn mrt_with_lightfield_transport_matches_reference() {
        let mut rng = Lcg(12);
        let t = lightfield(&mut rng);
        let b = bundle(&mut rng, Some(t), false);
        let ld = direct(&mut rng, 21);
        let want = reference_mrt(&b, &ld.radiance);
        // The transport really contributes (compare with no transport).
        let local = reference_mrt(
            &Bundle {
                transport: None,
                ..b.clone()
            },
            &ld.radiance,
        );
        assert!(want
            .iter()
            .zip(&local)
            .any(|(a, l)| (a[0] - l[0]).abs() > 1e-3));
        let got = run(b, Method::Mrt, &ld);
        assert_close(&got, &want);
        assert_eq!(&got.radiance[19..], &[[0.0; 3]; 2]);
    }

    #[test]
    fn mrt_without_transport_is_local_only() {
        let mut rng = Lcg(13);
        let b = bundle(&mut rng, None, false);
        let ld = direct(&mut rng, 21);
        let want = reference_mrt(&b, &ld.radiance);
        assert_close(&run(b, Method::Mrt, &ld), &want);
    }

    #[test]
    fn full_matches_reference() {
        let mut rng = Lcg(14);
        let t = traced(&mut rng);
        let b = bundle(&mut rng, Some(t), true);
        let ld = direct(&mut rng, 21);
        let want = reference_full(&b, &ld.radiance);
        let got = run(b, Method::Full, &ld);
        assert_close(&got, &want);
        assert!(
            got.radiance[19..].iter().flatten().any(|&v| v != 0.0),
            "clutter texels are lit under Full"
        );
    }

    #[test]
    fn full_without_the_operator_is_an_error() {
        let mut rng = Lcg(15);
        let mut rt = Runtime::new(bundle(&mut rng, None, false));
        assert!(!rt.has_full());
        let ld = direct(&mut rng, 21);
        let mut out = IndirectLight::default();
        let err = rt.apply(Method::Full, &ld, &mut out).unwrap_err();
        assert_eq!(err, ApplyError::MissingFull);
        assert_eq!(
            err.to_string(),
            "this bundle has no dense operator; bake it with --full"
        );
    }

    #[test]
    fn wrong_direct_length_is_an_error_not_a_panic() {
        let mut rng = Lcg(16);
        let t = lightfield(&mut rng);
        let mut rt = Runtime::new(bundle(&mut rng, Some(t), true));
        let mut out = IndirectLight::default();
        for len in [0, 20, 22] {
            let ld = direct(&mut rng, len);
            for method in [Method::Mrt, Method::Full] {
                let err = rt.apply(method, &ld, &mut out).unwrap_err();
                assert_eq!(
                    err,
                    ApplyError::DirectLength {
                        expected: 21,
                        got: len
                    }
                );
            }
        }
    }

    #[test]
    fn apply_twice_is_identical_and_does_not_allocate() {
        let mut rng = Lcg(17);
        let before = allocs();
        drop(std::hint::black_box(vec![1u8; 64]));
        assert!(allocs() > before, "the allocation counter works");
        for transport in [Some(traced(&mut rng)), Some(lightfield(&mut rng)), None] {
            let mut rt = Runtime::new(bundle(&mut rng, transport, true));
            let ld = direct(&mut rng, 21);
            for method in [Method::Mrt, Method::Full] {
                // A wrong-length `out` is resized; a right-length one is reused.
                let mut out = IndirectLight {
                    radiance: vec![[9.0; 3]; 5],
                };
                rt.apply(method, &ld, &mut out).unwrap();
                let first = out.clone();
                let before = allocs();
                rt.apply(method, &ld, &mut out).unwrap();
                rt.apply(method, &ld, &mut out).unwrap();
                assert_eq!(allocs(), before, "{method:?}: apply allocated");
                assert_eq!(out, first, "{method:?}: not deterministic");
                // Stale values in `out` do not leak into the result.
                out.radiance.fill([f32::NAN; 3]);
                rt.apply(method, &ld, &mut out).unwrap();
                assert_eq!(out, first);
            }
        }
    }

    #[test]
    fn encode_decode_round_trip_gives_the_same_output() {
        let mut rng = Lcg(18);
        for transport in [traced(&mut rng), lightfield(&mut rng)] {
            let b = bundle(&mut rng, Some(transport), true);
            let decoded = Bundle::decode(&b.encode()).expect("hand-built bundle decodes");
            assert_eq!(decoded, b);
            let ld = direct(&mut rng, 21);
            for method in [Method::Mrt, Method::Full] {
                assert_eq!(
                    run(b.clone(), method, &ld),
                    run(decoded.clone(), method, &ld)
                );
            }
        }
    }

    #[test]
    fn inconsistent_hand_built_bundles_are_refused() {
        let mut rng = Lcg(19);
        let t = lightfield(&mut rng);
        let good = bundle(&mut rng, Some(t), true);
        assert!(Runtime::try_new(good.clone()).is_ok());

        let mut b = good.clone();
        b.blocks[2].texel_offset = 18;
        assert!(Runtime::try_new(b).is_err(), "block past the layout");
        let mut b = good.clone();
        b.blocks[0].shape = 7;
        assert!(Runtime::try_new(b).is_err(), "missing shape");
        let mut b = good.clone();
        b.shapes[1].t_db.data.pop();
        assert!(Runtime::try_new(b).is_err(), "short matrix");
        let mut b = good.clone();
        if let Some(TransportOps::Lightfield(e)) = &mut b.transport {
            e[0].target_face = 5;
        }
        assert!(Runtime::try_new(b).is_err(), "opening the shape lacks");
        let mut b = good.clone();
        b.full.as_mut().unwrap().cols[0] = 21;
        assert!(Runtime::try_new(b).is_err(), "full column out of range");
        let mut b = good;
        b.layout.albedo.pop();
        assert!(Runtime::try_new(b).is_err(), "albedo length");
    }
}
