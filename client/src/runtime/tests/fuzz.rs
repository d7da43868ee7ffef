//! Mutated encodings through the runtime: byte mutations and truncations of hand-built bundles
//! (raw and with repaired checksums, half inside one focus section); whatever `Bundle::decode`
//! accepts must make a [`Runtime`] that applies every method, the probes and `irradiance_at`
//! without a panic. What the decoder itself must do with these bytes (refuse truncations, accept
//! some repaired mutations and refuse others) is asserted by `proto/tests/decode_fuzz.rs`, on
//! the same bundles with the same seeds.

use super::*;
use crate::probes::irradiance_at;
use lightfarm_proto::testing::{
    drt_bundle_with_every_list, factored_bundle, fuzz_mutations, with_gather, with_tiles,
};

/// Decodes `bytes`; a decoded bundle must make a runtime, which must apply every method
/// without panicking. Returns whether the bytes decoded.
fn decode_and_apply(bytes: &[u8]) -> bool {
    let Ok(bundle) = Bundle::decode(bytes) else {
        return false;
    };
    let mut rt = match Runtime::try_new(bundle) {
        Ok(rt) => rt,
        Err(e) => panic!("decode accepted a bundle the runtime refuses: {e}"),
    };
    let ld = DirectLight {
        radiance: vec![[0.5, 1.0, 1.5]; rt.n_texels()],
    };
    let mut out = IndirectLight::default();
    for method in [Method::Mrt, Method::Full, Method::Drt] {
        let _ = rt.apply(method, Bounces::One, &ld, &mut out);
    }
    let mut field = ProbeField::default();
    if rt.apply_probes(&ld, &mut field).is_ok() {
        let volume = rt.probe_volume().expect("apply_probes needs a volume");
        let o = volume.origin;
        let s = volume.spacing;
        for (g, n) in [
            ([0.5f32, 0.5, 0.5], [0.0f32, 1.0, 0.0]),
            ([1.0, 0.0, 0.3], [0.3, -0.2, 0.9]),
            ([-3.0, 9.0, 0.5], [-1.0, 0.0, 0.0]),
        ] {
            let pos = std::array::from_fn(|a| o[a] + s * g[a]);
            let e = irradiance_at(volume, &field, pos, n);
            assert!(e.iter().all(|x| *x >= 0.0), "irradiance {e:?}");
        }
    }
    true
}

#[test]
fn mutated_drt_bundles_never_panic() {
    let mut rng = Lcg(24);
    let b = drt_bundle(&mut rng, false, true, true);
    fuzz_bundle(
        &mut rng,
        &b,
        lightfarm_proto::bundle::section::DRT_REPLACING,
    );
}

#[test]
fn mutated_probe_bundles_never_panic() {
    let mut rng = Lcg(36);
    for drt in [true, false] {
        let b = probe_bundle(&mut rng, drt);
        fuzz_bundle(&mut rng, &b, lightfarm_proto::bundle::section::PROBES);
    }
}

/// [`fuzz_mutations`] of `b` (the mutations `proto/tests/decode_fuzz.rs` checks decode on):
/// whatever decodes must run; some repaired mutations (a changed value) still decode, so the
/// runtime ran on them.
fn fuzz_bundle(rng: &mut Lcg, b: &Bundle, focus: u32) {
    let counts = fuzz_mutations(rng, b, focus, |_, bytes| decode_and_apply(bytes));
    assert!(
        counts.accepted > 0,
        "{} of {} decoded",
        counts.accepted,
        counts.tried
    );
}

#[test]
fn mutated_shared_source_bases_never_panic() {
    let mut rng = Lcg(27);
    let b = factored_bundle(&mut rng);
    fuzz_bundle(
        &mut rng,
        &b,
        lightfarm_proto::bundle::section::TRANSPORT_SOURCE_BASES,
    );
}

#[test]
fn mutated_drt_bundles_with_replaced_texels_never_panic() {
    let mut rng = Lcg(38);
    let mut b = drt_bundle(&mut rng, false, true, true);
    b.drt.as_mut().unwrap().replaced = vec![0, 5, 9];
    fuzz_bundle(
        &mut rng,
        &b,
        lightfarm_proto::bundle::section::DRT_REPLACING,
    );
}

#[test]
fn mutated_drt_bundles_with_escaped_gather_counts_never_panic() {
    let mut rng = Lcg(39);
    let mut b = drt_bundle(&mut rng, false, true, true);
    with_gather(&mut rng, &mut b, 700);
    fuzz_bundle(
        &mut rng,
        &b,
        lightfarm_proto::bundle::section::DRT_WIDE_COUNTS,
    );
}

#[test]
fn mutated_drt_bundles_with_gather_tiles_never_panic() {
    let mut rng = Lcg(41);
    let mut b = drt_bundle(&mut rng, false, true, true);
    with_gather(&mut rng, &mut b, 700);
    with_tiles(&mut b, 2);
    fuzz_bundle(
        &mut rng,
        &b,
        lightfarm_proto::bundle::section::DRT_TILED_GATHER,
    );
}

#[test]
fn mutated_drt_bundles_with_packed_index_lists_never_panic() {
    let mut rng = Lcg(42);
    let b = drt_bundle_with_every_list(&mut rng);
    fuzz_bundle(
        &mut rng,
        &b,
        lightfarm_proto::bundle::section::DRT_PACKED_LISTS,
    );
}

#[test]
fn mutated_drt_bundles_with_a_modelled_gather_never_panic() {
    let mut rng = Lcg(43);
    let b = drt_bundle_with_every_list(&mut rng);
    fuzz_bundle(
        &mut rng,
        &b,
        lightfarm_proto::bundle::section::DRT_MODELLED_GATHER,
    );
}
