//! The per-frame runtime: direct light in, indirect light out, by the bundle's operators.
//!
//! Owns the decoded [`Bundle`] and every scratch buffer the per-frame work needs, so
//! [`Runtime::apply`] and [`Runtime::apply_probes`] allocate nothing (they only resize `out`
//! when its size is wrong; the exceptions: the first `Converged` solve with [`Method::Drt`], or
//! with [`Method::Mrt`] on a bundle that has DRT, makes its coefficient-space operators, see
//! `reduced` and `reduced_drt`).
//!
//! [`Method::Mrt`] (modular radiance transfer), for every block B and channel c:
//! 1. `b_B = T_d→b · l_d^B` (l_d^B: the block's texel range of direct radiance);
//! 2. `l_ind^B = U_b · b_B`;
//! 3. transport: Traced adds `M · b_A` for every entry (target B, source A); Lightfield sums
//!    `r_(B,face) = Σ M · b_A` over the entries into each opening, then adds `U_r · r_(B,face)`
//!    with the shape's (first) opening of that face;
//! 4. multiplies by the receiving texel's albedo. Texels in no block (clutter) get 0.
//!
//! [`Method::Drt`] (delta radiance transfer; needs the bundle's DRT section):
//! 1. steps 1–3 of MRT, albedo-free (block texels get `U_b b + transport`, every other texel 0),
//!    keeping every block's `b`; the section's `replaced` texels (`scene_gather: exact`, minor
//!    3) are set back to 0, their light being the exact gather alone;
//! 2. `c_j = t_dc · l_d[texel_offset .. texel_offset + t_dc.cols]` for every clutter object j;
//! 3. for every delta entry and each of its rows i: `out[rows[i]] += matrix.row(i) · x`, with
//!    `x` the source block's `b` or the source clutter object's `c`. Entries on block texels
//!    correct the MRT result; entries on clutter texels are those texels' whole indirect light;
//!    then the exact gather: `out[rows[i]] += Σ_k values[k] · l_d[cols[k]]`;
//! 4. multiplies by the receiving texel's albedo.
//!
//! [`Method::Full`]: `l_ind = ρ ⊙ (F · l_d)` with the bundle's sparse dense-bounce operator F.
//!
//! [`Runtime::apply_sh`] (in module `sh_apply`) turns direct light into SH incident radiance per
//! texel of normal-mapped surfaces, from the bundle's `sh` section.
//!
//! [`Runtime::apply_probes`] (needs the bundle's probe volume): MRT step 1 and, when the bundle
//! has a DRT section, DRT step 2 (the same code as `apply`, so the same `b` and `c`) on the
//! blocks and clutter objects the probe entries read, then for
//! every probe entry and each of its rows i: `field[rows[i]] += matrix.row(i) · x` per channel
//! (`matrix.row(i) · (mix · x)` for a low-rank entry), `x` as in DRT step 3 and `rows[i] =
//! probe · 9 + coefficient`. No albedo: a probe holds
//! incident radiance at a point, not a surface's outgoing radiance (see [`crate::probes`]).
//!
//! Relighting by the change ([`Runtime::apply_delta`], in `incremental`): the operators are
//! linear, so when lights move, `apply_delta` adds the indirect light of the change of direct
//! light to the previous output, skipping every product whose input is zero.
//!
//! Bounces ([`Bounces`]): every method above is one linear map `A` from the radiance leaving
//! texels to the one-bounce indirect radiance leaving them (same units in and out, albedo
//! included), so bounce k+1 is `A` applied to bounce k, and all bounces are the Neumann series
//! `I = Σ_{k≥1} A^k L_d` (the fixed point `I = A (L_d + I)`; Wavelet Radiance Transport §3, the
//! global transport operator). [`Bounces::One`] is the papers' light; [`Bounces::Fixed`] sums
//! exactly n bounces, one by one; [`Bounces::Converged`] (the default) solves `(I − A) I = A L_d`
//! by restarted GMRES (module `krylov`) to a relative residual of `tolerance`: the Neumann sum to
//! the same error in fewer applications of `A` (maze with pillars, T=8, at 1e-3: 8 applications
//! and 4.2e-4 relative L2 from 100 bounces, where the series needs 18 bounces for 7.7e-4); with
//! [`Method::Mrt`] the bounces after the first run in the blocks' coefficient space (module
//! `reduced`), with [`Method::Drt`] in the blocks' and clutter objects' (module `reduced_drt`,
//! where that reads under half a texel application's values); [`Runtime::set_reduced_bounces`]
//! picks the texel path instead;
//! [`Bounces::Feedback`] applies `A` once per call to the direct light plus the previous call's
//! indirect light (Enlighten's radiosity feedback), so repeated calls with steady lights converge
//! to `Converged` at one application each; [`Bounces::Warm`] is `Converged`'s accuracy at
//! `Feedback`'s cost while lights hold still: it starts from the previous call's answer, checks
//! it with one application and runs GMRES only on what is left (module `warm`).
//!
//! # Layout
//! - this file: the public types ([`Method`], [`Bounces`], [`Applied`], [`IndirectLight`],
//!   [`ApplyError`]), [`Runtime`] and its construction ([`Runtime::try_new`]: validation,
//!   symmetry unfolding, the scratch layout), the accessors, and [`Runtime::apply`] with the
//!   bounce modes (`One`, `Fixed`, `Converged`, `Feedback`) over one application of `A`.
//! - `packed_ops`: `PackedOps` (every operator packed for the kernels, indexed like the
//!   bundle's) and `BlockSlots` (one block's ranges in the block-major scratch).
//! - `mrt`: MRT steps 1–4 (`project_blocks`, `mrt_albedo_free`, `multiply_albedo`).
//! - `drt`: DRT steps 1–3 beyond MRT (`project_clutter`, `source_coefficients`,
//!   `add_drt_deltas` or `add_deltas_of` a kind of entry, `drop_replaced`, `add_direct_gather`) and `GatherByChange`, the
//!   gather's entries by the texel they read, for relighting by the change.
//! - `full`: [`Method::Full`], the sparse dense-bounce operator.
//! - `probes`: [`Runtime::apply_probes`], the probe volume's SH radiance from the blocks and
//!   clutter objects its entries read, and [`Runtime::apply_probes_delta`], the field of a
//!   change of light added where the probes read it.
//! - `sh_apply`: [`Runtime::apply_sh`] and [`ShLight`], SH incident radiance per texel.
//! - `kernels`: planar views of the scratch, the packed matrix-vector products, the block loop.
//! - `krylov`: the restarted GMRES of [`Bounces::Converged`].
//! - `reduced`: [`Bounces::Converged`] for MRT over the blocks' coefficients (`M = R D K`, made
//!   with the runtime when the bundle has no DRT, else on the first such solve) instead of
//!   texels.
//! - `reduced_drt`: [`Bounces::Converged`] for DRT over the blocks' and clutter objects'
//!   coefficients (the exact gather seen from the clutter's coefficients; made on the first such
//!   solve) instead of texels.
//! - `warm`: [`Bounces::Warm`], the solve that starts from the previous answer.
//! - `incremental`: [`Runtime::apply_delta`], relighting by the change of direct light: only
//!   the blocks, clutter objects and entries the change reaches do work, bounce by bounce.
//! - `delta_bounces`: more bounces of a change, each the sparse one-bounce application of the
//!   last, for `Converged` while its light matters (dropping the faintest units within the
//!   tolerance).
//! - `delta_feedback`: [`Bounces::Feedback`] by the change, one sparse bounce a call of the
//!   change and of the light added earlier and not yet bounced, where it is due (all bounces
//!   over the next calls, settling within [`Runtime::set_feedback_tolerance`]).
//! - `tests` (`tests/`): hand-built bundles against dense references, per concept.
//!
//! Invariants:
//! - A [`Runtime`] only exists for a bundle whose sizes and indices are consistent (checked in
//!   [`Runtime::try_new`]; always true of a bundle from `Bundle::decode`), so `apply` and
//!   `apply_probes` index without further checks and their only errors are the ones in
//!   [`ApplyError`].
//! - `apply` (except with [`Bounces::Feedback`] and [`Bounces::Warm`], whose state is the
//!   previous output: Warm's result then differs from `Converged`'s within the tolerance) and
//!   `apply_probes` are deterministic: the same direct light gives bit-identical output every
//!   call, whatever was applied before (they share scratch but each refills what it reads).
//! - Bounce loops end: `Converged` stops at [`MAX_BOUNCES`] applications or when a GMRES cycle
//!   no longer reduces the residual, and refuses an operator whose estimated gain (spectral
//!   radius) is ≥ 0.999 (e.g. albedo 1 in a closed room) with [`ApplyError::NotConverging`];
//!   any non-finite value is refused with [`ApplyError::NonFinite`]; the output is then zero,
//!   never NaN.
//! - Scratch vectors are channel-planar (channel c of an n-vector at `c·n .. (c+1)·n`), so
//!   every matrix row is one contiguous pass accumulating all three channels. Per-block scratch
//!   (coefficients `b`, opening lightfields) is block-major, so each block's work writes only
//!   its own ranges: blocks run independently, on one thread by default or on the rayon pool
//!   with the `rayon` feature and `Runtime::set_parallel`, with bit-identical results.
//! - Block texel ranges are ascending and disjoint (checked by `Bundle::validate`).

use lightfarm_proto::bundle::{Bundle, BundleError, ProbeVolume, TransportOps};

use crate::direct::DirectLight;
use crate::packed::PackedMatrix;
use crate::packed_gather::PackedGather;

mod delta_bounces;
mod delta_feedback;
mod drt;
mod full;
mod incremental;
mod kernels;
mod krylov;
mod mrt;
mod packed_ops;
mod probes;
mod reduced;
mod reduced_drt;
mod sh_apply;
mod warm;

pub use incremental::{merge_spans, DeltaApplied};
use krylov::{Krylov, Unsolved};
use packed_ops::{BlockSlots, PackedOps};
pub use sh_apply::ShLight;

/// Which operator turns direct into indirect light.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Method {
    /// The sparse dense-bounce operator over all texels (the bundle's `full`, if baked).
    Full,
    /// Modular radiance transfer: per-block operators plus inter-block transport.
    Mrt,
    /// Delta radiance transfer: MRT plus the clutter corrections of the bundle's DRT section.
    Drt,
}

/// How many bounces of indirect light [`Runtime::apply`] sums (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Bounces {
    /// The first bounce only: the papers' one-bounce indirect light.
    One,
    /// Exactly this many bounces (1 is [`Bounces::One`]; 0 is refused).
    Fixed(u32),
    /// All bounces, to an estimated relative error of `tolerance` (0 < tolerance < 1; see
    /// [`Applied::remaining_fraction`]). The default, with [`DEFAULT_TOLERANCE`].
    Converged { tolerance: f32 },
    /// One application per call of the direct light plus the previous call's indirect light
    /// (zero after [`Runtime::reset_feedback`], a method change or a new runtime). With
    /// [`Runtime::apply_delta`]: one sparse application per call of the change plus the light
    /// not yet bounced where it is due (module `delta_feedback`), settling to all bounces
    /// within [`Runtime::set_feedback_tolerance`] while the lights hold still.
    Feedback,
    /// All bounces to `tolerance` like [`Bounces::Converged`], starting from the last answer
    /// of `Converged` or `Warm` with the same method (the previous frame's): one application
    /// when the lights held still, a few GMRES steps on the change when they moved, a cold
    /// `Converged` solve when there is no previous answer (after [`Runtime::reset_feedback`],
    /// a method change or a new runtime).
    Warm { tolerance: f32 },
}

/// The default tolerance of [`Bounces::Converged`]: about 0.1% of the light.
pub const DEFAULT_TOLERANCE: f32 = 1e-3;

/// Applications of the one-bounce operator [`Bounces::Converged`] makes at the most.
pub const MAX_BOUNCES: u32 = 1000;

impl Default for Bounces {
    fn default() -> Bounces {
        Bounces::Converged {
            tolerance: DEFAULT_TOLERANCE,
        }
    }
}

impl From<lightfarm_proto::bounces::BounceCount> for Bounces {
    /// `1` → [`Bounces::One`], `n` → [`Bounces::Fixed`], `all` → the default `Converged`.
    fn from(b: lightfarm_proto::bounces::BounceCount) -> Bounces {
        use lightfarm_proto::bounces::BounceCount;
        match b {
            BounceCount::Fixed(1) => Bounces::One,
            BounceCount::Fixed(n) => Bounces::Fixed(n),
            BounceCount::All => Bounces::default(),
        }
    }
}

/// What one [`Runtime::apply`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Applied {
    /// Applications of the one-bounce operator: the bounces summed for `One`, `Fixed(n)` and
    /// `Feedback` (1); for `Converged`, the first bounce plus the GMRES iterations; for `Warm`,
    /// the check of the previous answer plus the GMRES iterations (or a cold solve's count).
    pub bounces: u32,
    /// `Converged` and `Warm`: the estimated error relative to all bounces (the largest
    /// channel's GMRES residual relative to its first bounce, for `Warm` the residual over
    /// `(1 − gain) ·` the light); `Feedback` by the change ([`Runtime::apply_delta`]): the
    /// estimated lag behind all bounces relative to the level's light
    /// ([`Runtime::feedback_lag`]); 0 otherwise.
    pub remaining_fraction: f32,
}

/// Indirect outgoing radiance, one RGB value per layout texel.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IndirectLight {
    pub radiance: Vec<[f32; 3]>,
}

/// Why [`Runtime::apply`] could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ApplyError {
    #[error("this bundle has no dense operator; bake it with --full")]
    MissingFull,
    #[error("this bundle has no DRT operators; bake a scene with clutter")]
    MissingDrt,
    #[error("direct light has {got} texels but the bundle's layout has {expected}")]
    DirectLength { expected: usize, got: usize },
    #[error("this bundle has no probe volume")]
    MissingProbes,
    #[error("this bundle has no SH responses; bake with settings.sh_responses")]
    MissingSh,
    #[error("bounces: Fixed(0) sums no bounce; use Fixed(n ≥ 1), One, Converged or Feedback")]
    NoBounces,
    #[error(
        "bounces: the Converged tolerance must lie in (0, 1), got {0} (the default is {DEFAULT_TOLERANCE})"
    )]
    BadTolerance(f32),
    #[error(
        "bounces: light does not converge (after {bounces} bounces each still keeps {ratio:.4} of \
         the last; an albedo of 1 in a closed room reflects forever); use Fixed(n) or One"
    )]
    NotConverging { bounces: u32, ratio: f32 },
    #[error(
        "bounces: bounce {bounce} produced a non-finite value (check albedo and direct light)"
    )]
    NonFinite { bounce: u32 },
    #[error(
        "probe field holds {got} probes but the bundle's probe volume has {expected}; fill it \
         with apply_probes before adding a change with apply_probes_delta"
    )]
    ProbeFieldSize { expected: usize, got: usize },
    #[error(
        "bounces: apply_delta with Feedback needs Mrt or Drt (the Full operator has no units to \
         shoot by); use One, Fixed(n), Converged or Warm with Full"
    )]
    DeltaFeedback,
}

/// Decoded bundle plus scratch, ready to apply every frame.
#[derive(Clone, Debug)]
pub struct Runtime {
    bundle: Bundle,
    n_texels: usize,
    blocks: Vec<BlockSlots>,
    /// Per opening of each block's shape, block-major: offset of its 3q lightfield values in
    /// `lf` (channel-planar within the opening).
    opening_lf: Vec<usize>,
    /// Per block: index of its first opening in `opening_lf`.
    first_opening: Vec<usize>,
    /// Transport entry indices grouped by target block (stable: ascending within a block).
    entry_order: Vec<u32>,
    /// Per transport entry (lightfield): index of the target opening in `opening_lf`.
    entry_opening: Vec<usize>,
    /// Scratch: direct radiance, planar, 3 × n_texels.
    ld: Vec<f32>,
    /// Scratch: direct radiance padded to four lanes, for the exact gather (empty without
    /// one).
    direct_padded: Vec<[f32; 4]>,
    /// Scratch: block coefficients, block-major, channel-planar within a block.
    b: Vec<f32>,
    /// Scratch: reduced lightfield coefficients, block-major (see `opening_lf`).
    lf: Vec<f32>,
    /// Per clutter object of the DRT section: `(start, m)`, its coefficients at
    /// `c[start .. start + 3m]`, channel-planar.
    clutter_coef: Vec<(usize, usize)>,
    /// Scratch: clutter coefficients.
    c: Vec<f32>,
    /// The bundle's operators packed for the kernels (see [`crate::packed`]).
    ops: PackedOps,
    /// Scratch of the packed products outside the per-block stages (clutter, deltas, probes).
    scratch: Vec<f32>,
    /// Whether per-block work runs on the current rayon pool (feature `rayon`).
    parallel: bool,
    /// Scratch of the bounce loop: the light one bounce leaves and the next bounce's output
    /// (n_texels each).
    bounce_in: Vec<[f32; 3]>,
    bounce_out: Vec<[f32; 3]>,
    /// [`Bounces::Feedback`]: the previous output and the method it was made with.
    feedback: Vec<[f32; 3]>,
    feedback_method: Option<Method>,
    /// [`Bounces::Converged`]'s GMRES workspace (`RESTART + 2` RGB texel vectors, 168 bytes a
    /// texel), made with the runtime so no frame allocates.
    krylov: Option<Krylov>,
    /// [`Bounces::Warm`]: the last all-bounce answer (`Converged` or `Warm`), the method it
    /// was made with and the operator's gain estimated by that method's last cold solve.
    warm: warm::WarmStart,
    /// [`Runtime::apply_delta`]: what each application's input reaches (None: everything, as
    /// in `apply`), the reach kept between calls so none allocates, the change's indirect
    /// light, and the block projections made.
    reach: Option<incremental::Reach>,
    spare_reach: Option<incremental::Reach>,
    delta_out: IndirectLight,
    blocks_projected: usize,
    /// Inside [`Runtime::apply_delta`]: the input is a signed change of light.
    by_change: bool,
    /// [`Runtime::apply_delta`] with an exact gather: its rows by the units they read (made on
    /// the first such call).
    gather_by_change: Option<drt::GatherByChange>,
    /// [`Runtime::apply_delta`] at one bounce: where `ld` and the change's light may be
    /// non-zero (made on the first such call); `ld_everywhere`: a full copy filled `ld`.
    sparse: Option<incremental::Sparse>,
    ld_everywhere: bool,
    /// [`Runtime::apply_probes`]: the blocks and clutter objects the probe entries read (made
    /// with the runtime; taken out while the probes run).
    probe_sources: Option<probes::ProbeSources>,
    /// [`Runtime::apply_delta`] over more bounces: the bounce-by-bounce sum's state (module
    /// `delta_bounces`, made on the first such call).
    chain: Option<delta_bounces::Chain>,
    /// [`Runtime::apply_delta`] with [`Bounces::Feedback`]: the unshot light and the units
    /// due (module `delta_feedback`, made on the first such call).
    progress: Option<delta_feedback::Progress>,
    /// L1 light (over texels and channels) of the last [`Runtime::apply`]'s answer, and per
    /// texel (`light_applied`); before any `apply`, of the light feedback by the change has
    /// added: the light that feedback is judged against (module `delta_feedback`).
    level_light: f64,
    texel_light: Vec<f32>,
    light_applied: bool,
    /// [`Bounces::Converged`] with [`Method::Mrt`] in coefficient space (module `reduced`):
    /// whether it is used, and its operators (made with the runtime for a bundle without DRT,
    /// else on the first such solve; `reduced_tried` once made, None for a lightfield
    /// transport).
    reduced_enabled: bool,
    reduced_tried: bool,
    reduced: Option<Box<reduced::ReducedMrt>>,
    /// [`Bounces::Converged`] with [`Method::Drt`] in coefficient space (module
    /// `reduced_drt`), made on the first such solve (None: the texel path).
    reduced_drt_tried: bool,
    reduced_drt: Option<Box<reduced_drt::ReducedDrt>>,
    /// Whether DRT's coefficient-space path is refused where it would not read well under
    /// half a texel application's values (always true outside tests).
    reduced_drt_gated: bool,
}

/// [`Bounces::Converged`] refuses an operator whose bounces keep at least this fraction of the
/// energy of the bounce before (measured as `1 − e_1/e_all`): its light would take thousands of
/// bounces, or never converge.
const MAX_CONVERGING_GAIN: f64 = 0.999;

/// The energy of a bounce: the sum of every texel's R, G and B (f64, so the sum of a large
/// level keeps its digits).
fn energy(light: &[[f32; 3]]) -> f64 {
    light
        .iter()
        .map(|v| v[0] as f64 + v[1] as f64 + v[2] as f64)
        .sum()
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
        bundle.validate()?;
        // Blocks instancing a shape through a box symmetry get their own permuted copy, so the
        // frame loop never permutes (the same memory and per-frame work as a bundle that
        // stored every orientation).
        let bundle = bundle.unfold_symmetries();
        // Compact transport with shared source bases reads as kind 2 everywhere (sizes, sums),
        // while the products apply Z' and the bases as shipped (PackedOps::new).
        let (bundle, factored) = bundle.unfold_source_bases();
        let n_texels = bundle.layout.n_texels();

        // Transport entries grouped by target block.
        let targets: Vec<u32> = match &bundle.transport {
            Some(TransportOps::Lightfield(e)) => e.iter().map(|e| e.target_block).collect(),
            Some(TransportOps::Traced(e)) => e.iter().map(|e| e.target_block).collect(),
            Some(TransportOps::Compact(e)) => e.iter().map(|e| e.target_block).collect(),
            Some(TransportOps::Factored(_)) => {
                unreachable!("kind 3 is unfolded at load (Runtime::try_new)")
            }
            None => Vec::new(),
        };
        let mut entry_order: Vec<u32> = (0..targets.len() as u32).collect();
        entry_order.sort_by_key(|&i| targets[i as usize]);
        let ops = PackedOps::new(&bundle, factored.as_ref());

        let (mut blocks, mut opening_lf, mut first_opening) = (Vec::new(), Vec::new(), Vec::new());
        let (mut n_coef, mut n_lf, mut next_entry) = (0, 0, 0);
        for (k, blk) in bundle.blocks.iter().enumerate() {
            let shape = &bundle.shapes[blk.shape as usize];
            let rank = shape.u_b.cols as usize;
            let lf_start = n_lf;
            first_opening.push(opening_lf.len());
            if matches!(bundle.transport, Some(TransportOps::Lightfield(_))) {
                for o in &shape.openings {
                    opening_lf.push(n_lf);
                    n_lf += 3 * o.u_r.cols as usize;
                }
            }
            let entries_start = next_entry;
            while next_entry < entry_order.len()
                && targets[entry_order[next_entry] as usize] == k as u32
            {
                next_entry += 1;
            }
            // Compact transport: scratch for the stacked source coefficients and Z's output.
            if let Some(TransportOps::Compact(entries)) = &bundle.transport {
                for &i in &entry_order[entries_start..next_entry] {
                    let e = &entries[i as usize];
                    n_lf += 3 * (e.z.cols as usize + e.z.rows as usize);
                }
            }
            let (u_b, t_db, u_r) = &ops.shapes[blk.shape as usize];
            let targeting = entry_order[entries_start..next_entry].iter();
            let scratch_start = n_lf;
            n_lf += PackedOps::scratch_len(
                [u_b, t_db]
                    .into_iter()
                    .chain(u_r)
                    .chain(targeting.clone().map(|&i| &ops.transport[i as usize]))
                    .chain(targeting.filter_map(|&i| ops.transport_z.get(i as usize))),
            );
            let texel_start = blk.texel_offset as usize;
            blocks.push(BlockSlots {
                coef_start: n_coef,
                rank,
                lf_start,
                lf_end: n_lf,
                scratch_start,
                texel_start,
                texel_end: texel_start + shape.u_b.rows as usize,
                entries_start,
                entries_end: next_entry,
            });
            n_coef += 3 * rank;
        }
        let mut entry_opening = Vec::new();
        if let Some(TransportOps::Lightfield(entries)) = &bundle.transport {
            for e in entries {
                let openings =
                    &bundle.shapes[bundle.blocks[e.target_block as usize].shape as usize].openings;
                // `validate` guarantees the opening exists.
                let oi = openings
                    .iter()
                    .position(|o| o.face == e.target_face)
                    .unwrap_or(0);
                entry_opening.push(first_opening[e.target_block as usize] + oi);
            }
        }

        let (mut clutter_coef, mut n_clutter_coef) = (Vec::new(), 0);
        if let Some(d) = &bundle.drt {
            for c in &d.clutter {
                clutter_coef.push((n_clutter_coef, c.t_dc.rows as usize));
                n_clutter_coef += 3 * c.t_dc.rows as usize;
            }
        }

        let mut runtime = Runtime {
            n_texels,
            blocks,
            opening_lf,
            first_opening,
            entry_order,
            entry_opening,
            ld: vec![0.0; 3 * n_texels],
            direct_padded: vec![[0.0; 4]; ops.gather.as_ref().map_or(0, |g| g.n_columns())],
            b: vec![0.0; n_coef],
            lf: vec![0.0; n_lf],
            clutter_coef,
            c: vec![0.0; n_clutter_coef],
            parallel: false,
            scratch: vec![
                0.0;
                PackedOps::scratch_len(
                    ops.clutter
                        .iter()
                        .chain(&ops.deltas)
                        .chain(ops.delta_mix.iter().flatten())
                        .chain(&ops.probes)
                        .chain(ops.probe_mix.iter().flatten())
                ) + 3 * ops
                    .delta_mix
                    .iter()
                    .chain(&ops.probe_mix)
                    .flatten()
                    .map(PackedMatrix::rows)
                    .max()
                    .unwrap_or(0)
            ],
            ops,
            bundle,
            bounce_in: vec![[0.0; 3]; n_texels],
            bounce_out: vec![[0.0; 3]; n_texels],
            feedback: vec![[0.0; 3]; n_texels],
            feedback_method: None,
            krylov: Some(Krylov::new(n_texels)),
            warm: warm::WarmStart::new(n_texels),
            reach: None,
            spare_reach: None,
            delta_out: IndirectLight {
                radiance: vec![[0.0; 3]; n_texels],
            },
            blocks_projected: 0,
            by_change: false,
            gather_by_change: None,
            sparse: None,
            ld_everywhere: true,
            probe_sources: None,
            chain: None,
            progress: None,
            level_light: 0.0,
            texel_light: vec![0.0; n_texels],
            light_applied: false,
            reduced_enabled: true,
            reduced_tried: false,
            reduced: None,
            reduced_drt_tried: false,
            reduced_drt: None,
            reduced_drt_gated: true,
        };
        if runtime.bundle.drt.is_none() {
            runtime.prepare_reduced();
        }
        runtime.probe_sources = Some(probes::ProbeSources::new(&runtime));
        Ok(runtime)
    }

    /// Forgets the light [`Bounces::Feedback`] feeds back (the next call starts from one
    /// bounce, as after a cut to another level), the unshot light of
    /// [`Runtime::apply_delta`] with `Feedback` (the answer is taken as converged) and the
    /// answer [`Bounces::Warm`] starts from (its next call is a cold `Converged` solve).
    pub fn reset_feedback(&mut self) {
        self.feedback.fill([0.0; 3]);
        self.feedback_method = None;
        self.warm.forget();
        if let Some(p) = self.progress.as_mut() {
            p.forget();
        }
        if !self.light_applied {
            // The light feedback by the change had added (module `delta_feedback`).
            self.texel_light.fill(0.0);
            self.level_light = 0.0;
        }
    }

    /// Runs the per-block work of [`Runtime::apply`] on the current rayon thread pool
    /// (`rayon::ThreadPool::install` picks the pool). Results are bit-identical to the
    /// single-thread path.
    #[cfg(feature = "rayon")]
    pub fn set_parallel(&mut self, parallel: bool) {
        self.parallel = parallel;
    }

    /// Bytes of operator data one [`Runtime::apply`] with `method` reads (packed values and
    /// their 8-bit parameters, row indices of sparse rows), for comparing frame time with memory
    /// bandwidth.
    pub fn operator_bytes_per_frame(&self, method: Method) -> usize {
        let b = &self.bundle;
        if method == Method::Full {
            return b.full.as_ref().map_or(0, |f| 8 * f.values.len());
        }
        let ops = &self.ops;
        let sum = |m: &[PackedMatrix]| m.iter().map(PackedMatrix::bytes).sum::<usize>();
        let mut bytes = 0;
        for blk in &b.blocks {
            let (u_b, t_db, u_r) = &ops.shapes[blk.shape as usize];
            bytes += u_b.bytes() + t_db.bytes();
            if matches!(b.transport, Some(TransportOps::Lightfield(_))) {
                bytes += sum(u_r);
            }
        }
        bytes += sum(&ops.transport) + sum(&ops.transport_z);
        if method == Method::Drt {
            if let Some(d) = &b.drt {
                bytes += sum(&ops.clutter) + sum(&ops.deltas);
                bytes += d.entries.iter().map(|e| 4 * e.rows.len()).sum::<usize>();
                bytes += ops.gather.as_ref().map_or(0, PackedGather::bytes);
            }
        }
        bytes
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

    /// Whether [`Method::Drt`] is available (the bundle has a DRT section).
    pub fn has_drt(&self) -> bool {
        self.bundle.drt.is_some()
    }

    /// Whether [`Runtime::apply_probes`] is available (the bundle has a probe volume).
    pub fn has_probes(&self) -> bool {
        self.bundle.probes.is_some()
    }

    /// The bundle's probe volume (grid and operators), for [`crate::irradiance_at`].
    pub fn probe_volume(&self) -> Option<&ProbeVolume> {
        self.bundle.probes.as_ref()
    }

    /// Turns direct light into indirect light by `method`, summing `bounces` bounces (see the
    /// module doc), and writes every texel of `out` (resized to the texel count if its length
    /// is wrong; otherwise no allocation). On an error `out` holds zeros (or is untouched for
    /// the argument errors, checked first).
    pub fn apply(
        &mut self,
        method: Method,
        bounces: Bounces,
        direct: &DirectLight,
        out: &mut IndirectLight,
    ) -> Result<Applied, ApplyError> {
        let n = self.n_texels;
        self.check_arguments(method, bounces, direct)?;
        if out.radiance.len() != n {
            out.radiance.clear();
            out.radiance.resize(n, [0.0; 3]);
        }
        let result = match bounces {
            Bounces::One | Bounces::Fixed(1) => {
                self.apply_once(method, &direct.radiance, &mut out.radiance);
                Ok(Applied {
                    bounces: 1,
                    remaining_fraction: 0.0,
                })
            }
            Bounces::Fixed(count) => {
                self.sum_bounces(method, &direct.radiance, &mut out.radiance, count)
            }
            Bounces::Converged { tolerance } => {
                let result = self.converge(method, &direct.radiance, &mut out.radiance, tolerance);
                self.remember_answer(method, &direct.radiance, &out.radiance, &result);
                result
            }
            Bounces::Warm { tolerance } => {
                let result =
                    self.converge_warm(method, &direct.radiance, &mut out.radiance, tolerance);
                self.remember_answer(method, &direct.radiance, &out.radiance, &result);
                result
            }
            Bounces::Feedback => self.apply_feedback(method, &direct.radiance, &mut out.radiance),
        };
        if result.is_err() {
            out.radiance.fill([0.0; 3]);
        } else if !self.by_change {
            for (l, v) in self.texel_light.iter_mut().zip(&out.radiance) {
                *l = v[0].abs() + v[1].abs() + v[2].abs();
            }
            self.level_light = self.texel_light.iter().map(|&x| x as f64).sum();
            self.light_applied = true;
        }
        result
    }

    /// The argument errors of [`Runtime::apply`] (and [`Runtime::apply_delta`]): the direct
    /// light's length, the method's section, the bounce mode.
    fn check_arguments(
        &self,
        method: Method,
        bounces: Bounces,
        direct: &DirectLight,
    ) -> Result<(), ApplyError> {
        if direct.radiance.len() != self.n_texels {
            return Err(ApplyError::DirectLength {
                expected: self.n_texels,
                got: direct.radiance.len(),
            });
        }
        if method == Method::Full && self.bundle.full.is_none() {
            return Err(ApplyError::MissingFull);
        }
        if method == Method::Drt && self.bundle.drt.is_none() {
            return Err(ApplyError::MissingDrt);
        }
        match bounces {
            Bounces::Fixed(0) => Err(ApplyError::NoBounces),
            Bounces::Converged { tolerance } | Bounces::Warm { tolerance }
                if !(tolerance > 0.0 && tolerance < 1.0) =>
            {
                Err(ApplyError::BadTolerance(tolerance))
            }
            _ => Ok(()),
        }
    }

    /// One application of the one-bounce operator: `out = A(light)`.
    fn apply_once(&mut self, method: Method, light: &[[f32; 3]], out: &mut [[f32; 3]]) {
        if self.reach.is_some() {
            self.find_reach(light);
        }
        match method {
            Method::Full => self.apply_full(light, out),
            Method::Mrt => {
                self.project_blocks(light);
                self.mrt_albedo_free(out);
                self.multiply_albedo(out);
            }
            Method::Drt => {
                self.project_blocks(light);
                self.mrt_albedo_free(out);
                self.drop_replaced(out);
                self.project_clutter();
                self.add_drt_deltas(out);
                self.add_direct_gather(light, out);
                self.multiply_albedo(out);
            }
        }
    }

    /// [`Bounces::Fixed`]: `out = Σ_{k=1..count} A^k(direct)`, bounce by bounce.
    fn sum_bounces(
        &mut self,
        method: Method,
        direct: &[[f32; 3]],
        out: &mut [[f32; 3]],
        count: u32,
    ) -> Result<Applied, ApplyError> {
        self.apply_once(method, direct, out);
        if !energy(out).is_finite() {
            return Err(ApplyError::NonFinite { bounce: 1 });
        }
        let mut light = std::mem::take(&mut self.bounce_in);
        let mut next = std::mem::take(&mut self.bounce_out);
        light.copy_from_slice(out);
        let mut result = Ok(Applied {
            bounces: count,
            remaining_fraction: 0.0,
        });
        for bounce in 2..=count {
            self.apply_once(method, &light, &mut next);
            for (o, v) in out.iter_mut().zip(&next) {
                o[0] += v[0];
                o[1] += v[1];
                o[2] += v[2];
            }
            if !energy(&next).is_finite() || !energy(out).is_finite() {
                result = Err(ApplyError::NonFinite { bounce });
                break;
            }
            std::mem::swap(&mut light, &mut next);
        }
        self.bounce_in = light;
        self.bounce_out = next;
        result
    }

    /// [`Bounces::Converged`]: `out` solves `(I − A) out = A(direct)` by restarted GMRES
    /// ([`krylov`]) to `tolerance`, then is checked to be light: the operator's gain (its
    /// spectral radius, estimated from the Ritz values of the first Arnoldi cycle) is below
    /// 0.999 — an operator of gain ≥ 1 has no all-bounce light, yet its linear system has a
    /// solution — and per channel the result carries at least the first bounce's energy.
    fn converge(
        &mut self,
        method: Method,
        direct: &[[f32; 3]],
        out: &mut [[f32; 3]],
        tolerance: f32,
    ) -> Result<Applied, ApplyError> {
        if self.reduced_enabled {
            let reduced = match method {
                Method::Mrt => self.converge_reduced(direct, out, tolerance),
                Method::Drt => self.converge_reduced_drt(direct, out, tolerance),
                Method::Full => None,
            };
            if let Some(result) = reduced {
                return result;
            }
        }
        let mut first = std::mem::take(&mut self.bounce_in);
        self.apply_once(method, direct, &mut first);
        if !energy(&first).is_finite() {
            self.bounce_in = first;
            return Err(ApplyError::NonFinite { bounce: 1 });
        }
        let mut krylov = self.take_krylov();
        let solved = krylov.solve(
            &mut |v, w| self.apply_once(method, v, w),
            &first,
            out,
            tolerance as f64,
            MAX_BOUNCES - 1,
        );
        self.krylov = Some(krylov);
        let channel_energy = |v: &[[f32; 3]], c: usize| v.iter().map(|x| x[c] as f64).sum::<f64>();
        // Light: per channel, all bounces carry at least the first bounce's energy. A change
        // of light (`apply_delta`) is signed, so only its gain is checked.
        let light = self.by_change
            || (0..3).all(|c| {
                let (e1, e) = (channel_energy(&first, c), channel_energy(out, c));
                e1 <= 0.0 || e >= 0.99 * e1
            });
        self.bounce_in = first;
        self.converge_outcome(solved, light)
    }

    /// What a `Converged` solve (over texels or coefficients) returns: the applications and the
    /// residual when it solved and the result is light (`light`: at least the first bounce's
    /// energy per channel) of gain below [`MAX_CONVERGING_GAIN`], else the refusal.
    fn converge_outcome(
        &mut self,
        solved: Result<krylov::Solved, Unsolved>,
        light: bool,
    ) -> Result<Applied, ApplyError> {
        let refused = |applications: u32, gain: f64| ApplyError::NotConverging {
            bounces: applications + 1,
            ratio: if gain.is_finite() { gain as f32 } else { 1.0 },
        };
        match solved {
            Ok(s) if light && s.gain < MAX_CONVERGING_GAIN => {
                self.warm.solved(s.gain);
                Ok(Applied {
                    bounces: s.applications + 1,
                    remaining_fraction: s.residual as f32,
                })
            }
            Ok(s) => Err(refused(s.applications, s.gain.max(MAX_CONVERGING_GAIN))),
            Err(Unsolved::Stalled {
                applications, gain, ..
            }) => Err(refused(applications, gain)),
            Err(Unsolved::NonFinite { application }) => Err(ApplyError::NonFinite {
                bounce: application + 1,
            }),
        }
    }

    /// The GMRES workspace (given back by the caller; made anew only if it was lost).
    fn take_krylov(&mut self) -> Krylov {
        match self.krylov.take() {
            Some(k) if k.len() == self.n_texels => k,
            _ => Krylov::new(self.n_texels),
        }
    }

    /// [`Bounces::Feedback`]: `out = A(direct + previous out)`, then remembers `out`.
    fn apply_feedback(
        &mut self,
        method: Method,
        direct: &[[f32; 3]],
        out: &mut [[f32; 3]],
    ) -> Result<Applied, ApplyError> {
        if self.feedback_method != Some(method) {
            self.feedback.fill([0.0; 3]);
            self.feedback_method = Some(method);
        }
        let mut light = std::mem::take(&mut self.bounce_in);
        for ((l, d), f) in light.iter_mut().zip(direct).zip(&self.feedback) {
            *l = [d[0] + f[0], d[1] + f[1], d[2] + f[2]];
        }
        self.apply_once(method, &light, out);
        self.bounce_in = light;
        if !energy(out).is_finite() {
            self.reset_feedback();
            return Err(ApplyError::NonFinite { bounce: 1 });
        }
        self.feedback.copy_from_slice(out);
        Ok(Applied {
            bounces: 1,
            remaining_fraction: 0.0,
        })
    }
}

#[cfg(test)]
mod tests;
