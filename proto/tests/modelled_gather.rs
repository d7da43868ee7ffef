//! Format 2.8's DRT section (kind 23): kind 22's layout whose exact gather is range-coded under
//! contexts from its neighbouring rows (gather form 3, `gather_model`). The writer writes only
//! kind 23, with the gather in form 3 wherever a bake's gather is (its weights counts of one
//! unit, its rows ascending); it decodes to the same bundle as the kind 22 a 2.7 writer wrote;
//! and form 3 is refused inside kind 22, so a 2.7 reader, which skips kind 23, never meets it.

use lightfarm_proto::bundle::{section, Bundle};
use lightfarm_proto::testing::{drt_bundle_with_every_list, join_sections, Lcg};

/// `sections` with the DRT section's kind changed from 23 to 22.
fn as_kind_22(mut sections: Vec<(u32, Vec<u8>)>) -> Vec<u8> {
    let drt = sections
        .iter_mut()
        .find(|(k, _)| *k == section::DRT_MODELLED_GATHER)
        .expect("a kind 23 DRT section");
    drt.0 = section::DRT_PACKED_LISTS;
    join_sections(&sections)
}

/// Whether `b`'s DRT section, as this writer writes it, holds its gather in form 3: read as
/// kind 22 (forms 0–2 only) it is then refused for its gather flag.
fn gather_is_modelled(b: &Bundle) -> bool {
    match Bundle::decode(&as_kind_22(b.raw_sections())) {
        Err(e) => {
            assert!(e.to_string().contains("unknown gather flag 3"), "{e}");
            true
        }
        Ok(decoded) => {
            assert_eq!(&decoded, b, "kind 23 without form 3 is kind 22's layout");
            false
        }
    }
}

#[test]
fn the_writer_writes_kind_23_with_a_modelled_gather_that_decodes_to_the_same_bundle() {
    for seed in [101, 102, 103] {
        let b = drt_bundle_with_every_list(&mut Lcg(seed));
        let kinds: Vec<u32> = b.raw_sections().iter().map(|(k, _)| *k).collect();
        assert!(kinds.contains(&section::DRT_MODELLED_GATHER), "{kinds:?}");
        assert!(!kinds.contains(&section::DRT_PACKED_LISTS), "{kinds:?}");
        assert!(gather_is_modelled(&b), "seed {seed}");
        assert_eq!(Bundle::decode(&b.encode()).expect("decodes"), b);
        let as_2_7 = b.raw_sections_as_2_7();
        assert!(as_2_7.iter().any(|(k, _)| *k == section::DRT_PACKED_LISTS));
        assert_eq!(Bundle::decode(&join_sections(&as_2_7)).expect("decodes"), b);
    }
}

#[test]
fn a_gather_whose_weights_are_not_counts_stays_in_form_2_inside_kind_23() {
    let mut b = drt_bundle_with_every_list(&mut Lcg(104));
    let g = b.drt.as_mut().unwrap().direct_gather.as_mut().unwrap();
    g.values[0] = 0.3;
    assert!(!gather_is_modelled(&b));
    assert_eq!(Bundle::decode(&b.encode()).expect("decodes"), b);
}

#[test]
fn a_baked_bundle_has_its_gather_modelled() {
    // The decode fuzzer's seed: `lightfarm bake client/fuzz/seed-scene.json --codec u8`
    // (`client/fuzz/make-seeds.sh`), a real bake's gather.
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../client/fuzz/corpus/decode/tiny-u8.lfb"
    );
    let b = Bundle::decode(&std::fs::read(path).expect("the seed")).expect("decodes");
    let g = b.drt.as_ref().unwrap().direct_gather.as_ref().unwrap();
    assert!(g.cols.len() > 100, "{} entries", g.cols.len());
    assert!(gather_is_modelled(&b));
}
