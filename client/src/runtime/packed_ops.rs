//! The bundle's operators in the form the per-frame kernels read, and where each block's work
//! sits in the runtime's scratch vectors.
//!
//! [`PackedOps`] holds every operator the stages multiply, packed by [`crate::packed`] (8-row
//! panels, 8 bits where the decoded values lie on an 8-bit grid), indexed like the bundle's own
//! lists: entry i of a section is packed at index i. Operators stay albedo-free, in the bundle's
//! units (radiance → coefficients → radiance). [`BlockSlots`] is one block's ranges in the
//! block-major scratch (`b`, `lf`), in `out` and in `entry_order`, filled by
//! [`Runtime::try_new`](super::Runtime::try_new).
//!
//! Invariants: both are built once per runtime and never change per frame; a block's slots are
//! disjoint from every other block's, which is what lets blocks run independently (see
//! `kernels::for_each_block`); scratch lengths ([`PackedOps::scratch_len`]) are the largest any
//! product of the listed matrices needs, so no frame allocates.

use std::sync::Arc;

use lightfarm_proto::bundle::{Bundle, SourceBases, TransportOps};

use crate::packed::PackedMatrix;
use crate::packed_gather::PackedGather;

/// Where one block's data sits in the block-major scratch vectors.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct BlockSlots {
    /// `b[coef_start .. coef_start + 3r]`: the block's r coefficients, channel-planar.
    pub(super) coef_start: usize,
    pub(super) rank: usize,
    /// `lf[lf_start .. lf_end]`: the reduced lightfields of the block's openings.
    pub(super) lf_start: usize,
    pub(super) lf_end: usize,
    /// `lf[scratch_start .. lf_end]`: scratch of the block's packed products.
    pub(super) scratch_start: usize,
    /// `out[texel_start .. texel_end]`: the block's texels.
    pub(super) texel_start: usize,
    pub(super) texel_end: usize,
    /// `entry_order[entries_start .. entries_end]`: transport entries that target the block.
    pub(super) entries_start: usize,
    pub(super) entries_end: usize,
}

/// Every operator the per-frame stages read, packed, indexed like the bundle's.
#[derive(Clone, Debug, Default)]
pub(super) struct PackedOps {
    /// Per shape: `(U_b, T_d→b, U_r per opening)`.
    pub(super) shapes: Vec<(PackedMatrix, PackedMatrix, Vec<PackedMatrix>)>,
    /// Per transport entry: its matrix (traced, lightfield) or `(Y, Z)` as two (compact).
    pub(super) transport: Vec<PackedMatrix>,
    pub(super) transport_z: Vec<PackedMatrix>,
    /// Per DRT clutter object: `t_dc`.
    pub(super) clutter: Vec<PackedMatrix>,
    /// Per DRT delta entry: its matrix and, for a low-rank entry, its `mix`.
    pub(super) deltas: Vec<PackedMatrix>,
    pub(super) delta_mix: Vec<Option<PackedMatrix>>,
    /// Per probe-volume entry: its matrix and, for a low-rank entry (format 2.3), its `mix`.
    pub(super) probes: Vec<PackedMatrix>,
    pub(super) probe_mix: Vec<Option<PackedMatrix>>,
    /// The exact clutter gather (DRT, `clutter_gather: exact`).
    pub(super) gather: Option<PackedGather>,
    /// Per SH-response entry: `Y` and `Z`, and the scratch their products need.
    pub(super) sh_y: Vec<PackedMatrix>,
    pub(super) sh_z: Vec<PackedMatrix>,
    pub(super) sh_scratch: usize,
}

impl PackedOps {
    /// `factored`: the shared source bases `bundle`'s compact transport was unfolded from
    /// ([`Bundle::unfold_source_bases`]); each `Z` is then packed as `Z' · blockdiag(Q)`.
    pub(super) fn new(bundle: &Bundle, factored: Option<&SourceBases>) -> PackedOps {
        let pack = PackedMatrix::new;
        let mut ops = PackedOps {
            shapes: bundle
                .shapes
                .iter()
                .map(|s| {
                    let u_r = s.openings.iter().map(|o| pack(&o.u_r)).collect();
                    (pack(&s.u_b), pack(&s.t_db), u_r)
                })
                .collect(),
            ..PackedOps::default()
        };
        match &bundle.transport {
            Some(TransportOps::Traced(e)) => {
                ops.transport = e.iter().map(|e| pack(&e.matrix)).collect()
            }
            Some(TransportOps::Lightfield(e)) => {
                ops.transport = e.iter().map(|e| pack(&e.matrix)).collect()
            }
            Some(TransportOps::Compact(e)) => {
                ops.transport = e.iter().map(|e| pack(&e.y)).collect();
                ops.transport_z = match factored {
                    Some(f) => factored_z(bundle, f),
                    None => e.iter().map(|e| pack(&e.z)).collect(),
                };
            }
            Some(TransportOps::Factored(_)) => {
                unreachable!("kind 3 is unfolded at load (Runtime::try_new)")
            }
            None => {}
        }
        if let Some(d) = &bundle.drt {
            ops.clutter = d.clutter.iter().map(|c| pack(&c.t_dc)).collect();
            ops.deltas = d.entries.iter().map(|e| pack(&e.matrix)).collect();
            ops.delta_mix = d.entries.iter().map(|e| e.mix.as_ref().map(pack)).collect();
            ops.gather = d
                .direct_gather
                .as_ref()
                .map(|g| PackedGather::new(g, bundle.layout.n_texels()));
        }
        if let Some(p) = &bundle.probes {
            ops.probes = p.entries.iter().map(|e| pack(&e.matrix)).collect();
            ops.probe_mix = p.entries.iter().map(|e| e.mix.as_ref().map(pack)).collect();
        }
        if let Some(sh) = &bundle.sh {
            ops.sh_y = sh.entries.iter().map(|e| pack(&e.y)).collect();
            ops.sh_z = sh.entries.iter().map(|e| pack(&e.z)).collect();
            ops.sh_scratch = PackedOps::scratch_len(ops.sh_y.iter().chain(&ops.sh_z));
        }
        ops
    }

    /// Largest scratch any of `matrices` needs.
    pub(super) fn scratch_len<'a>(matrices: impl IntoIterator<Item = &'a PackedMatrix>) -> usize {
        matrices
            .into_iter()
            .map(PackedMatrix::scratch_len)
            .max()
            .unwrap_or(0)
    }
}

/// Each receiver's `Z` of compact transport with shared source bases, as `Z' · blockdiag(Q)`
/// with every basis packed once and shared.
fn factored_z(bundle: &Bundle, f: &SourceBases) -> Vec<PackedMatrix> {
    let rank = |b: u32| {
        bundle.shapes[bundle.blocks[b as usize].shape as usize]
            .u_b
            .cols as usize
    };
    let mut bases: Vec<Option<Arc<PackedMatrix>>> = vec![None; bundle.blocks.len()];
    for b in &f.bases {
        bases[b.source_block as usize] = Some(Arc::new(PackedMatrix::new(&b.q)));
    }
    f.entries
        .iter()
        .map(|e| {
            let sources = e
                .sources
                .iter()
                .map(|&s| (rank(s), bases[s as usize].clone()))
                .collect();
            PackedMatrix::factored(&e.z, sources)
        })
        .collect()
}
