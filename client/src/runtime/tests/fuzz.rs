//! Mutated encodings through the runtime: byte mutations and truncations of hand-built bundles
//! (raw and with repaired checksums, half inside one focus section); whatever `Bundle::decode`
//! accepts must make a [`Runtime`] that applies every method, the probes and `irradiance_at`
//! without a panic. What the decoder itself must do with these bytes (refuse truncations, accept
//! some repaired mutations and refuse others) is asserted by `proto/tests/decode_fuzz.rs`, on
//! the same bundles with the same seeds.

use super::*;
use crate::probes::irradiance_at;

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
    // The test bundle has low-rank entries, so its DRT section is the minor-2 kind.
    fuzz_bundle(&mut rng, &b, lightfarm_proto::bundle::section::DRT_LOW_RANK);
}

#[test]
fn mutated_probe_bundles_never_panic() {
    let mut rng = Lcg(36);
    for drt in [true, false] {
        let b = probe_bundle(&mut rng, drt);
        fuzz_bundle(&mut rng, &b, lightfarm_proto::bundle::section::PROBES);
    }
}

/// Byte mutations and truncations of `b`'s encoding, half of them inside the section of
/// kind `focus`: none may panic (decode, runtime, apply, apply_probes, irradiance_at). The
/// same mutations as `fuzz_decode` in `proto/tests/decode_fuzz.rs`, which asserts what decode
/// makes of them; here, that whatever decodes runs.
fn fuzz_bundle(rng: &mut Lcg, b: &Bundle, focus: u32) {
    let bytes = b.encode();
    assert!(decode_and_apply(&bytes));
    let sections = b.raw_sections();
    assert!(decode_and_apply(&join_sections(&sections)));
    let focus_at = sections
        .iter()
        .position(|(kind, _)| *kind == focus)
        .expect("the bundle has the focus section");
    let mutate = |byte: &mut u8, rng: &mut Lcg| {
        *byte = match rng.next_u32() % 3 {
            0 => *byte ^ (1 + rng.next_u32() % 255) as u8,
            1 => rng.next_u32() as u8,
            _ => [0x00, 0x01, 0x7f, 0x80, 0xff][rng.next_u32() as usize % 5],
        };
    };
    let (mut decoded, mut tried) = (0, 0);

    // Single bytes anywhere (the checksums catch nearly all of these).
    for _ in 0..1500 {
        let mut m = bytes.clone();
        let at = rng.next_u32() as usize % m.len();
        mutate(&mut m[at], rng);
        decode_and_apply(&m);
    }
    // Truncations of the file (decode refuses them all: proto's decode_fuzz).
    for _ in 0..500 {
        let len = rng.next_u32() as usize % bytes.len();
        decode_and_apply(&bytes[..len]);
    }
    // Single bytes inside a section, checksum repaired, so validation sees them; half in
    // the focus section.
    for k in 0..3000 {
        let mut s = sections.clone();
        let i = if k % 2 == 0 {
            focus_at
        } else {
            rng.next_u32() as usize % s.len()
        };
        let payload = &mut s[i].1;
        let at = rng.next_u32() as usize % payload.len();
        mutate(&mut payload[at], rng);
        tried += 1;
        decoded += decode_and_apply(&join_sections(&s)) as usize;
    }
    // Sections truncated inside, length and checksum repaired.
    for k in 0..1000 {
        let mut s = sections.clone();
        let i = if k % 2 == 0 {
            focus_at
        } else {
            rng.next_u32() as usize % s.len()
        };
        let len = rng.next_u32() as usize % s[i].1.len();
        s[i].1.truncate(len);
        decode_and_apply(&join_sections(&s));
    }
    // Some repaired mutations (a changed value) still decode, so the runtime ran on them
    // (that many are refused is proto's decode_fuzz).
    assert!(decoded > 0, "{decoded} of {tried} decoded");
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
