//! Decoder fuzzing: byte mutations and truncations of hand-built bundles (raw and with
//! lengths and checksums repaired, so edits reach validation; half of them inside one focus
//! section) through `Bundle::decode`. Any bytes give `Ok` or `Err`, never a panic; a truncated
//! file is refused; a bundle decode accepts also passes `Bundle::validate`; some repaired
//! mutations (a changed value) still decode and others are refused.
//!
//! The bundles, seeds and mutations are those of the client's runtime fuzzing
//! (`client/src/runtime/tests/fuzz.rs`), which checks that whatever decodes also makes a
//! runtime that applies without a panic; both build their bundles with
//! `lightfarm_proto::testing` (feature `testing`), so both fuzz the same bytes.

#![allow(clippy::needless_range_loop)]

use lightfarm_proto::bundle::{section, Bundle};
use lightfarm_proto::testing::{
    drt_bundle, drt_bundle_with_every_list, factored_bundle, fuzz_mutations, probe_bundle,
    with_gather, with_tiles, Lcg, Mutation,
};

/// Decodes `bytes`; a decoded bundle must pass `validate` (what the runtime checks before
/// anything else). Returns whether the bytes decoded.
fn decodes(bytes: &[u8]) -> bool {
    let Ok(bundle) = Bundle::decode(bytes) else {
        return false;
    };
    if let Err(e) = bundle.validate() {
        panic!("decode accepted a bundle validate refuses: {e}");
    }
    true
}

/// [`fuzz_mutations`] of `b` through `decode`: none may panic, truncated files never decode,
/// and of the repaired section-byte mutations some decode and some do not.
fn fuzz_decode(rng: &mut Lcg, b: &Bundle, focus: u32) {
    let counts = fuzz_mutations(rng, b, focus, |mutation, bytes| {
        let decoded = decodes(bytes);
        if mutation == Mutation::TruncatedFile {
            assert!(!decoded, "truncated to {}", bytes.len());
        }
        decoded
    });
    assert!(
        counts.accepted > 0 && counts.accepted < counts.tried,
        "{} of {} decoded",
        counts.accepted,
        counts.tried
    );
}

#[test]
fn mutated_drt_bundles_never_panic() {
    let mut rng = Lcg(24);
    let b = drt_bundle(&mut rng, false, true, true);
    fuzz_decode(&mut rng, &b, section::DRT_REPLACING);
}

#[test]
fn mutated_shared_source_bases_never_panic() {
    let mut rng = Lcg(27);
    let b = factored_bundle(&mut rng);
    fuzz_decode(&mut rng, &b, section::TRANSPORT_SOURCE_BASES);
}

#[test]
fn mutated_probe_bundles_never_panic() {
    let mut rng = Lcg(36);
    for drt in [true, false] {
        let b = probe_bundle(&mut rng, drt);
        fuzz_decode(&mut rng, &b, section::PROBES);
    }
}

#[test]
fn mutated_drt_bundles_with_replaced_texels_never_panic() {
    let mut rng = Lcg(38);
    let mut b = drt_bundle(&mut rng, false, true, true);
    b.drt.as_mut().unwrap().replaced = vec![0, 5, 9];
    fuzz_decode(&mut rng, &b, section::DRT_REPLACING);
}

#[test]
fn mutated_drt_bundles_with_escaped_gather_counts_never_panic() {
    let mut rng = Lcg(39);
    let mut b = drt_bundle(&mut rng, false, true, true);
    with_gather(&mut rng, &mut b, 700);
    fuzz_decode(&mut rng, &b, section::DRT_WIDE_COUNTS);
}

#[test]
fn mutated_drt_bundles_with_gather_tiles_never_panic() {
    let mut rng = Lcg(40);
    let mut b = drt_bundle(&mut rng, false, true, true);
    with_gather(&mut rng, &mut b, 700);
    with_tiles(&mut b, 2);
    fuzz_decode(&mut rng, &b, section::DRT_TILED_GATHER);
}

#[test]
fn mutated_drt_bundles_with_packed_index_lists_never_panic() {
    let mut rng = Lcg(42);
    let b = drt_bundle_with_every_list(&mut rng);
    fuzz_decode(&mut rng, &b, section::DRT_PACKED_LISTS);
}

#[test]
fn mutated_drt_bundles_with_a_modelled_gather_never_panic() {
    let mut rng = Lcg(43);
    let b = drt_bundle_with_every_list(&mut rng);
    fuzz_decode(&mut rng, &b, section::DRT_MODELLED_GATHER);
}
