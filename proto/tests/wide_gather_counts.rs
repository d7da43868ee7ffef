//! Format 2.5's DRT section (kind 20): an exact gather with a hit count over 255 keeps its
//! weights as escaped counts (one byte, 255 followed by the rest as a varint) instead of f32;
//! the bundle decodes to the same gather, bit for bit. A 2.6 writer wrote a gather whose counts
//! all fit a byte as kind 13, and kind 13 refuses the escaped form (which is why it is a kind of
//! its own: a 2.4 reader skips kind 20 and lights by MRT rather than failing). The current
//! writer's kind 22 holds either form (`tiled_gather.rs`); its bundles decode here too.

use lightfarm_proto::bundle::{section, Bundle};
use lightfarm_proto::testing::{drt_bundle, join_sections, with_gather, Lcg};

/// `b`'s DRT section as a 2.6 writer wrote it: its kind and raw payload.
fn drt_section(b: &Bundle) -> (u32, Vec<u8>) {
    let sections = b.raw_sections_as_2_6();
    let drt: Vec<_> = sections
        .into_iter()
        .filter(|(k, _)| [section::DRT_REPLACING, section::DRT_WIDE_COUNTS].contains(k))
        .collect();
    assert_eq!(drt.len(), 1, "one DRT section");
    drt.into_iter().next().unwrap()
}

#[test]
fn counts_over_a_byte_are_written_as_kind_20_and_decode_to_the_same_gather() {
    let mut rng = Lcg(71);
    for max_count in [256u32, 300, 1024, 70_000] {
        let mut b = drt_bundle(&mut rng, false, true, true);
        with_gather(&mut rng, &mut b, max_count);
        let (kind, _) = drt_section(&b);
        assert_eq!(kind, section::DRT_WIDE_COUNTS, "max count {max_count}");
        let as_2_6 = join_sections(&b.raw_sections_as_2_6());
        assert_eq!(Bundle::decode(&as_2_6).expect("decodes"), b);
        let decoded = Bundle::decode(&b.encode()).expect("decodes");
        assert_eq!(decoded, b, "max count {max_count}");
        let g = decoded.drt.unwrap().direct_gather.unwrap();
        assert_eq!(g.values[0], max_count as f32 / 1024.0);
    }
}

#[test]
fn counts_within_a_byte_stay_kind_13() {
    let mut rng = Lcg(72);
    let mut b = drt_bundle(&mut rng, false, true, true);
    with_gather(&mut rng, &mut b, 255);
    assert_eq!(drt_section(&b).0, section::DRT_REPLACING);
    assert_eq!(Bundle::decode(&b.encode()).expect("decodes"), b);
}

/// Kind 20's payload relabelled as kind 13 is refused, naming the weight form; the escaped
/// counts take one byte per entry where f32 took four (the same gather with one weight that is
/// not a count falls back to f32).
#[test]
fn kind_13_refuses_escaped_counts_and_they_take_a_byte_per_entry() {
    let mut rng = Lcg(73);
    let mut b = drt_bundle(&mut rng, false, true, true);
    with_gather(&mut rng, &mut b, 600);
    let mut sections = b.raw_sections_as_2_6();
    for s in sections.iter_mut() {
        if s.0 == section::DRT_WIDE_COUNTS {
            s.0 = section::DRT_REPLACING;
        }
    }
    let relabelled = join_sections(&sections);
    let err = Bundle::decode(&relabelled).expect_err("kind 13 with escaped counts");
    assert!(err.to_string().contains("unknown weight form 2"), "{err}");

    let (_, wide) = drt_section(&b);
    let values = &b
        .drt
        .as_ref()
        .unwrap()
        .direct_gather
        .as_ref()
        .unwrap()
        .values;
    let counts: Vec<u32> = values.iter().map(|v| (v * 1024.0) as u32).collect();
    // Each count of 255 or more: a 255 byte and a varint of the rest (1 byte below 128).
    let escapes: usize = counts
        .iter()
        .filter(|&&c| c >= 255)
        .map(|&c| if c - 255 < 128 { 1 } else { 2 })
        .sum();
    let mut f32_form = b.clone();
    let g = f32_form
        .drt
        .as_mut()
        .unwrap()
        .direct_gather
        .as_mut()
        .unwrap();
    g.values[1] = 0.3;
    let (kind, f32_bytes) = drt_section(&f32_form);
    assert_eq!(kind, section::DRT_REPLACING);
    // f32: `values:f32s` (8 + 4n); escaped: unit, n, n bytes, the escapes' length and bytes.
    let n = counts.len();
    assert!(n > 20 && escapes > 0, "{n} entries, {escapes} escape bytes");
    assert_eq!(
        f32_bytes.len() - wide.len(),
        (8 + 4 * n) - (4 + 8 + n + 8 + escapes),
        "{n} entries"
    );
}
