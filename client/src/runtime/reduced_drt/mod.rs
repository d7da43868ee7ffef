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
//!
//! # Layout
//! - this file: `M`'s terms and shared products as applied ([`ReducedDrt`]), one application
//!   of `M`, and the solve (`Runtime::converge_reduced_drt`: right-hand side, GMRES, texel
//!   expansion, light check).
//! - `pieces`: how the pieces are made (`ReducedDrt::new`): the gather seen from each clutter
//!   object, projectors and producers, the gate on values read.

use lightfarm_proto::bundle::{Bundle, DeltaSource, TransportOps};

use super::drt::Deltas;
use super::kernels::{group, planar, set_matvec, stack_sources};
use super::krylov::Krylov;
use super::packed_ops::{BlockSlots, PackedOps};
use super::reduced::{from_planar, to_planar, Piece};
use crate::packed::PackedMatrix;

mod pieces;

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
    /// The values an application of `M` reads over those a texel application reads.
    pub(super) read_share: f64,
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
    /// Whether the bundle has the gather in low-rank form (entries over the light).
    light_entries: bool,
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

impl ReducedDrt {
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
        to_planar(self.groups.iter().copied(), &self.weight, v, &mut self.z_in);
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
        from_planar(self.groups.iter().copied(), &self.weight, &self.z_out, w);
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
            let clutter = self.bundle.drt.iter().flat_map(|d| d.clutter.iter());
            for (j, c) in clutter.enumerate() {
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
        red.first_energy = e1;
        let mut rhs = std::mem::take(&mut red.rhs);
        let mut solution = std::mem::take(&mut red.solution);
        let mut krylov = red.krylov.take().unwrap_or_else(|| Krylov::new(rhs.len()));
        from_planar(
            red.groups.iter().copied(),
            &red.weight,
            &red.z_out,
            &mut rhs,
        );
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
        to_planar(
            red.groups.iter().copied(),
            &red.weight,
            &solution,
            &mut red.z_in,
        );
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
            if red.light_entries {
                let n = self.n_texels;
                for (t, l) in light.iter().enumerate() {
                    for (ch, v) in l.iter().enumerate() {
                        self.ld[ch * n + t] = *v;
                    }
                }
                self.ld_everywhere = true;
                self.add_deltas_of(out, Deltas::OfLight);
            }
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
