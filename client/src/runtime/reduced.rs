//! [`Bounces::Converged`](super::Bounces::Converged) for [`Method::Mrt`](super::Method::Mrt) in
//! the blocks' coefficient space: the bounces after the first never go back to texels.
//!
//! MRT's one-bounce operator is `A = D K R`: `R` projects texel radiance on every block's
//! coefficients (`b_B = T_d→b l^B`), `K` expands coefficients to albedo-free texel radiance
//! (`U_b b_B` plus the transport into B) and `D` is the albedo. All bounces are
//! `Σ_{k≥1} A^k L_d = D K Σ_{k≥0} M^k R L_d` with `M = R D K`, so the runtime projects the direct
//! light once (`z₀ = R L_d`), solves `(I − M) w = z₀` by the same GMRES as the texel path
//! ([`super::krylov`]) and expands `w` once (`D K w`, MRT steps 2–4). `M` is small and its
//! pieces are made once (the albedo sits between `T_d→b` and `U_b`, so they depend on the
//! channel: one matrix per distinct albedo of the block, read once for the three channels, when
//! a block has at most two albedos; one per channel otherwise):
//! - per block, `T_d→b diag(ρ_c) U_b` (r × r);
//! - per transport entry into B, the entry seen from B's coefficients: compact
//!   `T_d→b diag(ρ_c) Y` (r_B × k, Z stays shared), traced `T_d→b diag(ρ_c) M` (r_B × r_A).
//!
//! A lightfield transport (`U_r` per opening) keeps the texel path. The nonzero eigenvalues of
//! `M` are `A`'s, so GMRES's gain estimate and refusal are the texel path's, and light is
//! checked as there (all bounces carry at least the first bounce's energy, from an energy
//! functional on the coefficients). GMRES runs on the coefficients weighted by the norms of
//! their `U_b` columns (the light each expands to): its tolerance then gives the texel path's
//! error in the same applications (maze: 3.3e-4 against 2.9e-4 at 1e-3, 8 applications each;
//! unweighted, 2.4e-3).
//!
//! [`Runtime::apply_delta`](super::Runtime::apply_delta) with `Converged` takes the same path
//! when the change's light fills the level (module `delta_bounces` otherwise): only the blocks
//! the change reaches project (`R ΔL_d`), then the solve and the expansion run over every
//! block, since the bounces spread the change through the transport.
//!
//! Units: coefficients as in `mrt` (`b`); the pieces map coefficients of light leaving a block
//! to coefficients of the next bounce's light leaving it.
//!
//! Invariants: made with the runtime for a bundle without DRT (MRT is its method; the first
//! MRT `Converged` solve makes them for a bundle with DRT, that call's one allocation) from the
//! bundle's decoded values, summed per albedo group in texel order
//! (deterministic); applied block by block on the calling thread, so results are bit-identical
//! at any thread count; sizes follow the runtime's `BlockSlots`.

use lightfarm_proto::bundle::{Bundle, Matrix, TransportOps};

use crate::packed::PackedMatrix;

use super::kernels::{planar, set_matvec, stack_sources};
use super::krylov::Krylov;
use super::packed_ops::{BlockSlots, PackedOps};

/// `M`'s pieces and the reduced solve's workspace.
#[derive(Clone, Debug)]
pub(super) struct ReducedMrt {
    /// Per block: `T_d→b diag(ρ_c) U_b`, r × r.
    own: Vec<Piece>,
    /// Per transport entry: compact `T diag(ρ_c) Y` (r_B × k), traced `T diag(ρ_c) M`
    /// (r_B × r_A).
    transport: Vec<Piece>,
    /// Scratch: planar input and output coefficients (the runtime's `b` layout), the stacked
    /// source coefficients and `Z`'s output of one compact entry, packed-product scratch.
    z_in: Vec<f32>,
    z_out: Vec<f32>,
    stacked: Vec<f32>,
    z_k: Vec<f32>,
    scratch: Vec<f32>,
    /// Per coefficient (RGB-vector index): the norm of its `U_b` column. GMRES runs on the
    /// coefficients scaled by it, so its residual weighs each coefficient by the light it
    /// expands to, as the texel path's does.
    weight: Vec<f32>,
    /// Per weighted coefficient and channel: the energy (sum over texels, albedo included) of
    /// the light it expands to, so `Σ energy · v` is the energy of `D K v` (f64).
    energy: Vec<[f64; 3]>,
    /// The GMRES workspace over coefficients (one RGB value per coefficient).
    krylov: Option<Krylov>,
    rhs: Vec<[f32; 3]>,
    solution: Vec<[f32; 3]>,
}

impl ReducedMrt {
    /// `M`'s pieces for `bundle` (None for a lightfield transport, which keeps the texel path).
    pub(super) fn new(
        bundle: &Bundle,
        blocks: &[BlockSlots],
        entry_order: &[u32],
        ops: &PackedOps,
    ) -> Option<ReducedMrt> {
        if matches!(bundle.transport, Some(TransportOps::Lightfield(_))) {
            return None;
        }
        let albedo = &bundle.layout.albedo;
        let block_albedo = |k: usize| {
            let s = &blocks[k];
            &albedo[s.texel_start..s.texel_end]
        };
        let own: Vec<Piece> = bundle
            .blocks
            .iter()
            .enumerate()
            .map(|(k, blk)| {
                let shape = &bundle.shapes[blk.shape as usize];
                project(&shape.t_db, block_albedo(k), &shape.u_b)
            })
            .collect();
        let mut transport = vec![Piece::Grouped(Vec::new()); entry_order.len()];
        let (mut widest, mut deepest) = (0, 0);
        for (k, slots) in blocks.iter().enumerate() {
            let t_db = &bundle.shapes[bundle.blocks[k].shape as usize].t_db;
            for &i in &entry_order[slots.entries_start..slots.entries_end] {
                let m = match &bundle.transport {
                    Some(TransportOps::Compact(e)) => {
                        let e = &e[i as usize];
                        widest = widest.max(e.z.cols as usize);
                        deepest = deepest.max(e.z.rows as usize);
                        &e.y
                    }
                    Some(TransportOps::Traced(e)) => &e[i as usize].matrix,
                    _ => continue,
                };
                transport[i as usize] = project(t_db, block_albedo(k), m);
            }
        }
        let n_coef = blocks.last().map_or(0, |s| s.coef_start + 3 * s.rank);
        let scratch = PackedOps::scratch_len(
            own.iter()
                .chain(&transport)
                .flat_map(Piece::packed)
                .chain(&ops.transport_z),
        );
        let weight = block_weights(bundle, blocks, n_coef / 3);
        let energy = energy_functional(bundle, blocks, &weight);
        Some(ReducedMrt {
            energy,
            weight,
            own,
            transport,
            z_in: vec![0.0; n_coef],
            z_out: vec![0.0; n_coef],
            stacked: vec![0.0; 3 * widest],
            z_k: vec![0.0; 3 * deepest],
            scratch: vec![0.0; scratch],
            krylov: Some(Krylov::new(n_coef / 3)),
            rhs: vec![[0.0; 3]; n_coef / 3],
            solution: vec![[0.0; 3]; n_coef / 3],
        })
    }

    /// `w = M v` over weighted RGB coefficient vectors (see [`to_planar`]).
    pub(super) fn apply(
        &mut self,
        bundle: &Bundle,
        blocks: &[BlockSlots],
        entry_order: &[u32],
        ops: &PackedOps,
        v: &[[f32; 3]],
        w: &mut [[f32; 3]],
    ) {
        to_planar(
            blocks.iter().map(block_group),
            &self.weight,
            v,
            &mut self.z_in,
        );
        let ReducedMrt {
            own,
            transport,
            z_in,
            z_out,
            stacked,
            z_k,
            scratch,
            ..
        } = self;
        for (k, s) in blocks.iter().enumerate() {
            let r = s.rank;
            let out_k = &mut z_out[s.coef_start..s.coef_start + 3 * r];
            let in_k = &z_in[s.coef_start..s.coef_start + 3 * r];
            out_k.fill(0.0);
            own[k].add(
                r,
                [&in_k[..r], &in_k[r..2 * r], &in_k[2 * r..]],
                out_k,
                scratch,
            );
            for &i in &entry_order[s.entries_start..s.entries_end] {
                let piece = &transport[i as usize];
                match &bundle.transport {
                    Some(TransportOps::Compact(entries)) => {
                        let e = &entries[i as usize];
                        let (z, width, depth) = (
                            &ops.transport_z[i as usize],
                            e.z.cols as usize,
                            e.z.rows as usize,
                        );
                        // Stack the sources' coefficients, channel-planar, then Z (shared by
                        // the channels, packed as the texel path reads it).
                        stack_sources(blocks, z_in, &e.sources, width, stacked, |_| true);
                        let u = &mut z_k[..3 * depth];
                        set_matvec(u, depth, z, planar(stacked, width, 0, width), scratch);
                        piece.add(r, planar(u, depth, 0, depth), out_k, scratch);
                    }
                    Some(TransportOps::Traced(entries)) => {
                        let a = &blocks[entries[i as usize].source_block as usize];
                        let x = planar(&z_in[a.coef_start..], a.rank, 0, a.rank);
                        piece.add(r, x, out_k, scratch);
                    }
                    _ => {}
                }
            }
        }
        from_planar(blocks.iter().map(block_group), &self.weight, &self.z_out, w);
    }
}

/// One of `M`'s pieces, `T diag(ρ_c) X` (r × w per channel, row-major).
#[derive(Clone, Debug)]
pub(super) enum Piece {
    /// `Σ_g ρ_g,c · P_g` over the block's distinct albedos (one per block in our scenes, one per
    /// material in general): each `P_g` read once for the three channels.
    Grouped(Vec<([f32; 3], PackedMatrix)>),
    /// One matrix per channel (four distinct albedos or more).
    PerChannel([Vec<f32>; 3]),
}

/// Albedo groups up to which a piece stays [`Piece::Grouped`]: its matrices then hold at most
/// the per-channel ones' values, and the packed kernel reads each once for the three channels
/// (cornell, a block of three albedos: DRT `Converged` 2.4-2.6× one bounce against 2.9-3.1×
/// with a matrix per channel; MRT 2.8× against 3.0×).
const MAX_GROUPS: usize = 3;

impl Piece {
    /// The piece from its per-albedo sums `(ρ, P_g)` (each r × w, row-major, in the order
    /// made): [`Piece::Grouped`] up to [`MAX_GROUPS`] albedos, else one matrix per channel.
    pub(super) fn from_groups(r: usize, w: usize, groups: Vec<([f32; 3], Vec<f32>)>) -> Piece {
        if groups.len() <= MAX_GROUPS {
            return Piece::Grouped(
                groups
                    .into_iter()
                    .map(|(rho, data)| {
                        let m = Matrix {
                            rows: r as u32,
                            cols: w as u32,
                            data,
                        };
                        (rho, PackedMatrix::f32(&m))
                    })
                    .collect(),
            );
        }
        let mut out = [
            vec![0.0f32; r * w],
            vec![0.0f32; r * w],
            vec![0.0f32; r * w],
        ];
        for (rho, p) in &groups {
            for c in 0..3 {
                for (o, g) in out[c].iter_mut().zip(p) {
                    *o += rho[c] * g;
                }
            }
        }
        Piece::PerChannel(out)
    }

    /// The packed matrices of a grouped piece.
    pub(super) fn packed(&self) -> impl Iterator<Item = &PackedMatrix> {
        let groups = match self {
            Piece::Grouped(g) => g.as_slice(),
            Piece::PerChannel(_) => &[],
        };
        groups.iter().map(|(_, m)| m)
    }

    /// `y_c += piece_c · x_c` for the three channels (`y` channel-planar, r per channel). The
    /// sums' order is fixed by the code, so results are bit-identical with or without AVX2
    /// (used where present, at run time, as in [`crate::packed`]).
    #[inline]
    pub(super) fn add(&self, r: usize, x: [&[f32]; 3], y: &mut [f32], scratch: &mut [f32]) {
        if let Piece::Grouped(groups) = self {
            for (rho, p) in groups {
                p.matvec(x, scratch, |i, d| {
                    y[i] += rho[0] * d[0];
                    y[r + i] += rho[1] * d[1];
                    y[2 * r + i] += rho[2] * d[2];
                });
            }
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked above); the function has no other contract.
            return unsafe { self.add_avx2(r, x, y) };
        }
        self.add_portable(r, x, y)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn add_avx2(&self, r: usize, x: [&[f32]; 3], y: &mut [f32]) {
        self.add_portable(r, x, y)
    }

    #[inline(always)]
    fn add_portable(&self, r: usize, x: [&[f32]; 3], y: &mut [f32]) {
        let (y0, rest) = y.split_at_mut(r);
        let (y1, y2) = rest.split_at_mut(r);
        match self {
            Piece::Grouped(_) => {}
            Piece::PerChannel(m) => {
                for (c, y) in [y0, y1, y2].into_iter().enumerate() {
                    let cols = x[c].len();
                    for (i, yi) in y.iter_mut().enumerate() {
                        *yi += dot(&m[c][i * cols..(i + 1) * cols], x[c]);
                    }
                }
            }
        }
    }
}

/// `T diag(ρ_c) X` (r × w per channel): `x` is n × w over the block's first n texels (a traced
/// entry may cover a prefix), `t` r × (≥ n), `albedo` the block's texels. Texels of equal
/// albedo are summed first (one channel-free product per albedo), in texel order within a
/// group and groups in order of their albedo's bits.
fn project(t: &Matrix, albedo: &[[f32; 3]], x: &Matrix) -> Piece {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked above); the function has no other contract.
        return unsafe { project_avx2(t, albedo, x) };
    }
    project_portable(t, albedo, x)
}

/// [`project`] compiled for AVX2: the same sums in the same order (each value accumulates over
/// texels in order; only the width of the vectors across a row differs).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn project_avx2(t: &Matrix, albedo: &[[f32; 3]], x: &Matrix) -> Piece {
    project_portable(t, albedo, x)
}

#[inline(always)]
fn project_portable(t: &Matrix, albedo: &[[f32; 3]], x: &Matrix) -> Piece {
    let (r, stride, n, w) = (
        t.rows as usize,
        t.cols as usize,
        x.rows as usize,
        x.cols as usize,
    );
    let mut order: Vec<usize> = (0..n).collect();
    // Stable: texel order within a group.
    order.sort_by_key(|&i| albedo[i].map(f32::to_bits));
    let mut groups: Vec<([f32; 3], Vec<f32>)> = Vec::new();
    let mut start = 0;
    while start < n {
        let rho = albedo[order[start]];
        let mut group = vec![0.0f32; r * w];
        let mut end = start;
        while end < n && albedo[order[end]] == rho {
            let texel = order[end];
            let row = &x.data[texel * w..(texel + 1) * w];
            for i in 0..r {
                let a = t.data[i * stride + texel];
                if a != 0.0 {
                    for (g, v) in group[i * w..(i + 1) * w].iter_mut().zip(row) {
                        *g += a * v;
                    }
                }
            }
            end += 1;
        }
        groups.push((rho, group));
        start = end;
    }
    Piece::from_groups(r, w, groups)
}

/// `a · b` in eight interleaved partial sums (a fixed order).
#[inline(always)]
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let n = a.len() - a.len() % 8;
    for (a, b) in a[..n].chunks_exact(8).zip(b[..n].chunks_exact(8)) {
        let a: &[f32; 8] = a.try_into().expect("eight lanes");
        let b: &[f32; 8] = b.try_into().expect("eight lanes");
        for l in 0..8 {
            acc[l] += a[l] * b[l];
        }
    }
    let mut s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
    for (a, b) in a[n..].iter().zip(&b[n..]) {
        s += a * b;
    }
    s
}

/// Per coefficient (RGB-vector index `coef_start / 3 + i`, `len` in all, 1 beyond the blocks'):
/// the norm of its `U_b` column, the light one unit of it expands to (1 where that is 0).
pub(super) fn block_weights(bundle: &Bundle, blocks: &[BlockSlots], len: usize) -> Vec<f32> {
    let mut weight = vec![1.0f32; len];
    for (k, blk) in bundle.blocks.iter().enumerate() {
        let u_b = &bundle.shapes[blk.shape as usize].u_b;
        let (rows, r) = (u_b.rows as usize, u_b.cols as usize);
        let base = blocks[k].coef_start / 3;
        for i in 0..r {
            let norm = (0..rows)
                .map(|t| (u_b.data[t * r + i] as f64).powi(2))
                .sum::<f64>()
                .sqrt() as f32;
            if norm > 0.0 && norm.is_finite() {
                weight[base + i] = norm;
            }
        }
    }
    weight
}

/// Per weighted coefficient and channel, the energy of the light it expands to:
/// `1ᵀ D_c K` (`U_b`'s columns, then each transport entry's, through `Z` for a compact one)
/// divided by the coefficient's weight.
fn energy_functional(bundle: &Bundle, blocks: &[BlockSlots], weight: &[f32]) -> Vec<[f64; 3]> {
    let mut g = vec![[0.0f64; 3]; weight.len()];
    let albedo = &bundle.layout.albedo;
    // `Σ_t ρ_c(t) m[t, j]` over the first `m.rows` texels from `start`.
    let column_sums = |m: &Matrix, start: usize| {
        let w = m.cols as usize;
        let mut sums = vec![[0.0f64; 3]; w];
        for t in 0..m.rows as usize {
            let rho = albedo[start + t];
            for (j, s) in sums.iter_mut().enumerate() {
                let v = m.data[t * w + j] as f64;
                for c in 0..3 {
                    s[c] += rho[c] as f64 * v;
                }
            }
        }
        sums
    };
    let mut add = |k: usize, sums: &[[f64; 3]]| {
        let base = blocks[k].coef_start / 3;
        for (i, s) in sums.iter().enumerate().take(blocks[k].rank) {
            for c in 0..3 {
                g[base + i][c] += s[c];
            }
        }
    };
    for (k, blk) in bundle.blocks.iter().enumerate() {
        add(
            k,
            &column_sums(
                &bundle.shapes[blk.shape as usize].u_b,
                blocks[k].texel_start,
            ),
        );
    }
    match &bundle.transport {
        Some(TransportOps::Traced(entries)) => {
            for e in entries {
                let start = blocks[e.target_block as usize].texel_start;
                add(e.source_block as usize, &column_sums(&e.matrix, start));
            }
        }
        Some(TransportOps::Compact(entries)) => {
            for e in entries {
                let y = column_sums(&e.y, blocks[e.target_block as usize].texel_start);
                let (depth, width) = (e.z.rows as usize, e.z.cols as usize);
                let mut col = 0;
                for &src in &e.sources {
                    let r = blocks[src as usize].rank;
                    let sums: Vec<[f64; 3]> = (col..col + r)
                        .map(|j| {
                            let mut s = [0.0f64; 3];
                            for (i, yi) in y.iter().enumerate().take(depth) {
                                let z = e.z.data[i * width + j] as f64;
                                for c in 0..3 {
                                    s[c] += yi[c] * z;
                                }
                            }
                            s
                        })
                        .collect();
                    add(src as usize, &sums);
                    col += r;
                }
            }
        }
        _ => {}
    }
    for (gi, w) in g.iter_mut().zip(weight) {
        for x in gi.iter_mut() {
            *x /= *w as f64;
        }
    }
    g
}

/// The energy per channel of `D K v` for weighted coefficients `v`.
fn energy_of(energy: &[[f64; 3]], v: &[[f32; 3]]) -> [f64; 3] {
    let mut e = [0.0f64; 3];
    for (g, x) in energy.iter().zip(v) {
        for c in 0..3 {
            e[c] += g[c] * x[c] as f64;
        }
    }
    e
}

/// Weighted RGB coefficients (index `start / 3 + i` of each channel-planar group `(start,
/// width)`, each `weight` times the runtime's coefficient) → the planar layout (a block's group
/// is `(coef_start, rank)`; `reduced_drt` adds the clutter objects' after the blocks').
pub(super) fn to_planar(
    groups: impl IntoIterator<Item = (usize, usize)>,
    weight: &[f32],
    v: &[[f32; 3]],
    z: &mut [f32],
) {
    for (start, width) in groups {
        let base = start / 3;
        for i in 0..width {
            for c in 0..3 {
                z[start + c * width + i] = v[base + i][c] / weight[base + i];
            }
        }
    }
}

/// The planar layout → weighted RGB coefficients (the inverse of [`to_planar`]).
pub(super) fn from_planar(
    groups: impl IntoIterator<Item = (usize, usize)>,
    weight: &[f32],
    z: &[f32],
    v: &mut [[f32; 3]],
) {
    for (start, width) in groups {
        let base = start / 3;
        for i in 0..width {
            for c in 0..3 {
                v[base + i][c] = z[start + c * width + i] * weight[base + i];
            }
        }
    }
}

/// A block's group in the planar coefficient layout.
fn block_group(s: &BlockSlots) -> (usize, usize) {
    (s.coef_start, s.rank)
}

impl super::Runtime {
    /// The energies per channel of the last reduced solve's first bounce and of all its
    /// bounces, from the coefficients alone (for tests).
    #[cfg(test)]
    pub(super) fn reduced_energies(&self) -> Option<([f64; 3], [f64; 3])> {
        let red = self.reduced.as_ref()?;
        Some((
            energy_of(&red.energy, &red.rhs),
            energy_of(&red.energy, &red.solution),
        ))
    }

    /// Makes `M`'s pieces once (nothing for a lightfield transport). [`super::Runtime::try_new`]
    /// calls it for a bundle without DRT (MRT is then its method, and no frame allocates);
    /// otherwise the first MRT `Converged` solve does.
    pub(super) fn prepare_reduced(&mut self) {
        if !self.reduced_tried {
            self.reduced_tried = true;
            self.reduced =
                ReducedMrt::new(&self.bundle, &self.blocks, &self.entry_order, &self.ops)
                    .map(Box::new);
        }
    }

    /// Uses the coefficient-space paths for [`Method::Mrt`](super::Method::Mrt)'s and
    /// [`Method::Drt`](super::Method::Drt)'s bounces (`true`, the default; modules `reduced` and
    /// `reduced_drt`) or the texel path ([`super::Bounces::Converged`]'s GMRES over texels, as
    /// for the full operator), for measuring one against the other. Both solve the same system
    /// to the same tolerance (DRT's, with clutter-to-clutter light through the gather taken in
    /// the clutter basis: see `reduced_drt`).
    pub fn set_reduced_bounces(&mut self, on: bool) {
        self.reduced_enabled = on;
    }

    /// [`super::Bounces::Converged`] for MRT in coefficient space (the module doc); None when
    /// the bundle's transport keeps the texel path.
    pub(super) fn converge_reduced(
        &mut self,
        direct: &[[f32; 3]],
        out: &mut [[f32; 3]],
        tolerance: f32,
    ) -> Option<Result<super::Applied, super::ApplyError>> {
        use super::MAX_BOUNCES;
        self.prepare_reduced();
        let mut red = self.reduced.take()?;
        // z₀ = R L_d; relighting by the change, only the blocks the change reaches project.
        if self.reach.is_some() {
            self.find_reach(direct);
        }
        self.project_blocks(direct);
        let mut rhs = std::mem::take(&mut red.rhs);
        let mut solution = std::mem::take(&mut red.solution);
        let mut krylov = red.krylov.take().unwrap_or_else(|| Krylov::new(rhs.len()));
        from_planar(
            self.blocks.iter().map(block_group),
            &red.weight,
            &self.b,
            &mut rhs,
        );
        let solved = {
            let (bundle, blocks, entry_order, ops) =
                (&self.bundle, &self.blocks, &self.entry_order, &self.ops);
            krylov.solve(
                &mut |v, w| red.apply(bundle, blocks, entry_order, ops, v, w),
                &rhs,
                &mut solution,
                tolerance as f64,
                MAX_BOUNCES - 1,
            )
        };
        // Light = D K w.
        to_planar(
            self.blocks.iter().map(block_group),
            &red.weight,
            &solution,
            &mut self.b,
        );
        (red.rhs, red.solution, red.krylov) = (rhs, solution, Some(krylov));
        self.reduced = Some(red);
        // The bounces reach every block the transport joins: expand all of them.
        let reach = self.reach.take();
        self.mrt_albedo_free(out);
        self.multiply_albedo(out);
        self.reach = reach;
        // Light, as the texel path checks it: per channel, all bounces carry at least the first
        // bounce's energy (`D K z₀`, from the coefficients alone).
        let red = self.reduced.as_ref()?;
        let (e1, e) = (
            energy_of(&red.energy, &red.rhs),
            energy_of(&red.energy, &red.solution),
        );
        // A change of light (`apply_delta`) is signed: only its gain is checked.
        let light = self.by_change || (0..3).all(|c| e1[c] <= 0.0 || e[c] >= 0.99 * e1[c]);
        if solved.is_ok() && !out.iter().flatten().all(|x| x.is_finite()) {
            return Some(Err(super::ApplyError::NonFinite { bounce: 1 }));
        }
        Some(self.converge_outcome(solved, light))
    }
}
