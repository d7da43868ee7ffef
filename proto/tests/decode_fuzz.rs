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
use lightfarm_proto::testing::{drt_bundle, join_sections, probe_bundle, Lcg};

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

/// Byte mutations and truncations of `b`'s encoding, half of them inside the section of
/// kind `focus`: none may panic, truncations never decode, and of the repaired mutations some
/// decode and some do not.
fn fuzz_decode(rng: &mut Lcg, b: &Bundle, focus: u32) {
    let bytes = b.encode();
    assert!(decodes(&bytes));
    let sections = b.raw_sections();
    assert!(decodes(&join_sections(&sections)));
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
        decodes(&m);
    }
    // Truncations of the file.
    for _ in 0..500 {
        let len = rng.next_u32() as usize % bytes.len();
        assert!(!decodes(&bytes[..len]), "truncated to {len}");
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
        decoded += decodes(&join_sections(&s)) as usize;
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
        decodes(&join_sections(&s));
    }
    // Some repaired mutations (a changed value) still decode; many are refused.
    assert!(
        decoded > 0 && decoded < tried,
        "{decoded} of {tried} decoded"
    );
}

#[test]
fn mutated_drt_bundles_never_panic() {
    let mut rng = Lcg(24);
    let b = drt_bundle(&mut rng, false, true, true);
    // The test bundle has low-rank entries, so its DRT section is the minor-2 kind.
    fuzz_decode(&mut rng, &b, section::DRT_LOW_RANK);
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
