//! [`Method::Mrt`](super::Method::Mrt) (modular radiance transfer), steps 1–4 of the module
//! doc: projecting direct light on every block's coefficients, the block's own operator plus
//! the inter-block transport into it, and the albedo. DRT reuses steps 1–3 (and 4); the
//! probes and the SH responses reuse step 1, so all see the same `ld` and `b`.
//!
//! Units: `ld` is direct outgoing radiance (W/m²/sr per channel), `b` the blocks' reduced
//! coefficients of it; `mrt_albedo_free` writes indirect radiance before the albedo, which
//! `multiply_albedo` applies last.
//!
//! Invariants: every block reads and writes only its own ranges (`BlockSlots`), so blocks run
//! one by one or on the rayon pool through `kernels::for_each_block` with bit-identical results;
//! texels in no block get 0; nothing allocates.

use lightfarm_proto::bundle::TransportOps;

use super::kernels::{
    acc_matvec, add_matvec, for_each_block, group, planar, set_matvec, set_matvec_columns,
    stack_sources,
};
use super::packed_ops::BlockSlots;
use super::Runtime;

impl Runtime {
    /// MRT step 1: fills the planar direct light `ld` and every block's coefficients `b`.
    pub(super) fn project_blocks(&mut self, direct: &[[f32; 3]]) {
        let n = self.n_texels;
        let Runtime {
            bundle,
            blocks,
            ld,
            b,
            lf,
            ops,
            parallel,
            reach,
            sparse,
            ld_everywhere,
            ..
        } = self;
        let reach = reach.as_ref();
        // Relighting by the change at one bounce: `ld` holds the reached units' light already
        // (zero elsewhere), and an unreached block's `b` is never read; a reached block's
        // projection reads only its columns of non-zero light.
        let sparse_state = sparse.as_ref().filter(|s| s.active);
        let sparse = sparse_state.is_some();

        // Direct light, planar.
        if !sparse {
            let (ld0, rest) = ld.split_at_mut(n);
            let (ld1, ld2) = rest.split_at_mut(n);
            for (((l, a), bb), c) in direct.iter().zip(ld0).zip(ld1).zip(ld2) {
                (*a, *bb, *c) = (l[0], l[1], l[2]);
            }
            *ld_everywhere = true;
        }

        // 1. b_B = T_d→b · l_d^B.
        let ld: &[f32] = ld;
        let coef_range = |k: usize| {
            let s: &BlockSlots = &blocks[k];
            (s.coef_start, s.coef_start + 3 * s.rank)
        };
        let scratch_range = |k: usize| (blocks[k].scratch_start, blocks[k].lf_end);
        for_each_block(
            0,
            blocks.len(),
            (b.as_mut_slice(), 0),
            (lf.as_mut_slice(), 0),
            &coef_range,
            &scratch_range,
            *parallel,
            &|k, b_k: &mut [f32], scratch: &mut [f32]| {
                if !Runtime::block_reached(reach, k) {
                    // No input on the block's texels: b = T · 0, without the product.
                    if !sparse {
                        b_k.fill(0.0);
                    }
                    return;
                }
                let blk = &bundle.blocks[k];
                let t_db = &ops.shapes[blk.shape as usize].1;
                let x = planar(ld, n, blk.texel_offset as usize, t_db.cols());
                match sparse_state.and_then(|s| s.nonzero_columns(k)) {
                    Some(columns) => {
                        set_matvec_columns(b_k, blocks[k].rank, t_db, x, columns, scratch)
                    }
                    None => set_matvec(b_k, blocks[k].rank, t_db, x, scratch),
                }
            },
        );
    }

    /// MRT steps 2–3, after [`Runtime::project_blocks`]: writes `U_b b + transport`
    /// (albedo-free) to block texels and 0 to every other texel. Each block's texels depend on
    /// its own work only, so blocks run independently.
    /// Relighting by the change at one bounce, `out` is zero outside the blocks it writes
    /// already (no fill) and blocks it does not write are skipped.
    pub(super) fn mrt_albedo_free(&mut self, out: &mut [[f32; 3]]) {
        let Runtime {
            bundle,
            blocks,
            opening_lf,
            first_opening,
            entry_order,
            entry_opening,
            b,
            lf,
            ops,
            parallel,
            reach,
            sparse,
            ..
        } = self;
        let sparse_state = sparse.as_ref().filter(|s| s.active);
        if sparse_state.is_none() {
            out.fill([0.0; 3]);
        }
        let b: &[f32] = b;
        let reach = reach.as_ref();
        let reached = |k: u32| Runtime::block_reached(reach, k as usize);
        let coefficients = |k: usize, cols: usize| {
            let s = &blocks[k];
            group(b, s.coef_start, s.rank, cols)
        };
        let texel_range = |k: usize| (blocks[k].texel_start, blocks[k].texel_end);
        let lf_range = |k: usize| (blocks[k].lf_start, blocks[k].lf_end);
        for_each_block(
            0,
            blocks.len(),
            (out, 0),
            (lf.as_mut_slice(), 0),
            &texel_range,
            &lf_range,
            *parallel,
            &|k, out_k: &mut [[f32; 3]], lf_k: &mut [f32]| {
                let slots = &blocks[k];
                if sparse_state.is_some_and(|s| !s.writes_block(k)) {
                    return;
                }
                let blk = &bundle.blocks[k];
                let (u_b, _, u_r) = &ops.shapes[blk.shape as usize];
                let (lf_k, scratch) = lf_k.split_at_mut(slots.scratch_start - slots.lf_start);
                // 2. l_ind^B = U_b · b_B.
                if reached(k as u32) {
                    add_matvec(out_k, u_b, coefficients(k, u_b.cols()), scratch);
                }
                let targeting = &entry_order[slots.entries_start..slots.entries_end];
                // 3. Inter-block transport into this block.
                match &bundle.transport {
                    Some(TransportOps::Traced(entries)) => {
                        for &i in targeting {
                            let e = &entries[i as usize];
                            if !reached(e.source_block) {
                                continue;
                            }
                            let m = &ops.transport[i as usize];
                            let x = coefficients(e.source_block as usize, m.cols());
                            add_matvec(&mut out_k[..m.rows()], m, x, scratch);
                        }
                    }
                    Some(TransportOps::Compact(entries)) => {
                        let mut at = 0;
                        for &i in targeting {
                            let e = &entries[i as usize];
                            let (y, z) = (&ops.transport[i as usize], &ops.transport_z[i as usize]);
                            let (width, k) = (z.cols(), z.rows());
                            if !e.sources.iter().any(|&s| reached(s)) {
                                at += 3 * (width + k);
                                continue;
                            }
                            let (x, rest) = lf_k[at..].split_at_mut(3 * width);
                            // Stack the sources' coefficients, channel-planar (an unreached
                            // source's are zero, and relighting by the change leaves its `b`
                            // unwritten).
                            stack_sources(blocks, b, &e.sources, width, x, reached);
                            let z_out = &mut rest[..3 * k];
                            set_matvec(z_out, k, z, planar(x, width, 0, width), scratch);
                            add_matvec(out_k, y, planar(z_out, k, 0, k), scratch);
                            at += 3 * (width + k);
                        }
                    }
                    Some(TransportOps::Lightfield(entries)) => {
                        lf_k.fill(0.0);
                        // Bit i: opening i of the shape receives light (openings past 63
                        // are always applied; their lightfield is then just zero).
                        let mut fed = 0u64;
                        for &i in targeting {
                            let e = &entries[i as usize];
                            if !reached(e.source_block) {
                                continue;
                            }
                            let m = &ops.transport[i as usize];
                            let opening = entry_opening[i as usize];
                            let q = m.rows();
                            let start = opening_lf[opening] - slots.lf_start;
                            let x = coefficients(e.source_block as usize, m.cols());
                            acc_matvec(&mut lf_k[start..start + 3 * q], q, m, x, scratch);
                            fed |= 1 << (opening - first_opening[k]).min(63);
                        }
                        for (oi, u_r) in u_r.iter().enumerate() {
                            if oi < 63 && fed & (1 << oi) == 0 {
                                continue;
                            }
                            let q = u_r.cols();
                            let start = opening_lf[first_opening[k] + oi] - slots.lf_start;
                            add_matvec(out_k, u_r, group(lf_k, start, q, q), scratch);
                        }
                    }
                    Some(TransportOps::Factored(_)) => {
                        unreachable!("kind 3 is unfolded at load (Runtime::try_new)")
                    }
                    None => {}
                }
            },
        );
    }

    /// Whether MRT writes block `k`'s texels under `reach`: the block is reached, or a
    /// transport entry into it (`targeting`) has a reached source.
    pub(super) fn block_written(
        reach: Option<&super::incremental::Reach>,
        transport: Option<&TransportOps>,
        targeting: &[u32],
        k: usize,
    ) -> bool {
        let reached = |s: u32| Runtime::block_reached(reach, s as usize);
        reached(k as u32)
            || match transport {
                Some(TransportOps::Traced(e)) => targeting
                    .iter()
                    .any(|&i| reached(e[i as usize].source_block)),
                Some(TransportOps::Lightfield(e)) => targeting
                    .iter()
                    .any(|&i| reached(e[i as usize].source_block)),
                Some(TransportOps::Compact(e)) => targeting
                    .iter()
                    .any(|&i| e[i as usize].sources.iter().any(|&s| reached(s))),
                Some(TransportOps::Factored(_)) => {
                    unreachable!("kind 3 is unfolded at load (Runtime::try_new)")
                }
                None => false,
            }
    }

    /// Multiplies every texel by its albedo (the operators are albedo-free).
    pub(super) fn multiply_albedo(&self, out: &mut [[f32; 3]]) {
        let n = out.len().min(self.bundle.layout.albedo.len());
        let rho = self.bundle.layout.albedo[..n].as_flattened();
        for (o, rho) in out[..n].as_flattened_mut().iter_mut().zip(rho) {
            *o *= rho;
        }
    }
}
