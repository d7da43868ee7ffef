//! DRT sections of the kinds older writers chose (6 without low-rank entries, 11 with them)
//! still decode, to the same [`Bundle`] a 2.6 writer's kind 13 gives. A 2.6 writer wrote kind 13
//! (or 20, when the gather has a count over 255: `wide_gather_counts.rs`; 21 with tiles:
//! `tiled_gather.rs`), with an empty replaced-texel list when nothing is replaced, and the
//! current writer writes only kind 23 (`modelled_gather.rs`), so these bytes come from bundles
//! already on disk (1.x files, and 2.x bundles of earlier writers).

use lightfarm_proto::bundle::{section, Bundle, DeltaSource};
use lightfarm_proto::testing::{drt_bundle, join_sections, Lcg};

/// The test bundle, without its low-rank and direct-light entries when `low_rank` is false
/// (a kind 6 section could not hold them).
fn bundle(rng: &mut Lcg, low_rank: bool) -> Bundle {
    let mut b = drt_bundle(rng, false, true, false);
    if !low_rank {
        let entries = &mut b.drt.as_mut().unwrap().entries;
        entries.retain(|e| e.mix.is_none() && !matches!(e.source, DeltaSource::Direct { .. }));
        assert!(!entries.is_empty());
    }
    b
}

/// `b`'s raw sections with its DRT section turned into `kind` (kind 13's payload without the
/// trailing `replaced:u32s`, which must be empty).
fn with_drt_kind(b: &Bundle, kind: u32) -> Vec<u8> {
    let mut sections = b.raw_sections_as_2_6();
    let drt = sections
        .iter_mut()
        .find(|(k, _)| *k == section::DRT_REPLACING)
        .expect("a 2.6 writer wrote DRT as kind 13");
    // An empty u32 list is its u64 length, 0.
    let tail = drt.1.split_off(drt.1.len() - 8);
    assert_eq!(tail, [0u8; 8], "replaced list not empty");
    drt.0 = kind;
    join_sections(&sections)
}

#[test]
fn the_writer_writes_only_kind_23_where_2_6_wrote_kind_13() {
    let mut rng = Lcg(61);
    for (low_rank, replaced) in [(false, false), (true, false), (true, true)] {
        let mut b = bundle(&mut rng, low_rank);
        if replaced {
            b.drt.as_mut().unwrap().replaced = vec![0, 5, 9];
        }
        let kinds: Vec<u32> = b.raw_sections().iter().map(|(k, _)| *k).collect();
        assert!(kinds.contains(&section::DRT_MODELLED_GATHER), "{kinds:?}");
        for older in [
            section::DRT_PACKED_LISTS,
            section::DRT,
            section::DRT_LOW_RANK,
            section::DRT_REPLACING,
            section::DRT_WIDE_COUNTS,
            section::DRT_TILED_GATHER,
        ] {
            assert!(!kinds.contains(&older), "{kinds:?}");
        }
        assert_eq!(Bundle::decode(&b.encode()).expect("decodes"), b);
        let as_2_6 = b.raw_sections_as_2_6();
        assert!(as_2_6.iter().any(|(k, _)| *k == section::DRT_REPLACING));
        assert_eq!(Bundle::decode(&join_sections(&as_2_6)).expect("decodes"), b);
    }
}

#[test]
fn kinds_6_and_11_decode_as_kind_13_with_nothing_replaced() {
    let mut rng = Lcg(62);
    // Without low-rank entries (what kind 6 held) and with them (kind 11).
    for (low_rank, kind) in [(false, section::DRT), (true, section::DRT_LOW_RANK)] {
        let b = bundle(&mut rng, low_rank);
        assert!(b.drt.as_ref().unwrap().replaced.is_empty());
        let older = Bundle::decode(&with_drt_kind(&b, kind)).expect("older kind decodes");
        assert_eq!(older, b, "kind {kind}");
    }
}
