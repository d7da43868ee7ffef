//! Transport kind 3 (compact transport with shared source bases) on the wire: it travels in
//! section 16, which older readers skip, never in section 4, which they read; a bundle without
//! it still decodes (what a 2.1 reader makes of a 2.2 bundle: the level without transport);
//! unfolding gives the kind-2 bundle it stands for.

use lightfarm_proto::bundle::{section, Bundle, TransportOps};
use lightfarm_proto::testing::{factored_bundle, join_sections, Lcg};

#[test]
fn shared_source_bases_travel_in_their_own_section_and_round_trip() {
    let b = factored_bundle(&mut Lcg(5));
    let sections = b.raw_sections();
    let kinds: Vec<u32> = sections.iter().map(|(k, _)| *k).collect();
    assert!(kinds.contains(&section::TRANSPORT_SOURCE_BASES));
    assert!(!kinds.contains(&section::TRANSPORT));
    assert_eq!(Bundle::decode(&b.encode()).unwrap(), b);

    // Unfolded, the same bundle is plain compact transport in section 4.
    let (unfolded, kept) = b.clone().unfold_source_bases();
    let Some(TransportOps::Factored(f)) = &b.transport else {
        unreachable!()
    };
    assert_eq!(kept.as_ref(), Some(f));
    unfolded.validate().unwrap();
    let kinds: Vec<u32> = unfolded.raw_sections().iter().map(|(k, _)| *k).collect();
    assert!(kinds.contains(&section::TRANSPORT));
    assert!(!kinds.contains(&section::TRANSPORT_SOURCE_BASES));
    let Some(TransportOps::Compact(entries)) = &unfolded.transport else {
        panic!("kind 3 unfolds to kind 2")
    };
    // Receiver a reads block b (r = 3) through its 2 × 3 basis: Z = Z' Q.
    let (z, zf, q) = (&entries[0].z, &f.entries[0].z, &f.bases[0].q);
    assert_eq!((z.rows, z.cols), (2, 3));
    for i in 0..2 {
        for c in 0..3 {
            let want: f64 = (0..2)
                .map(|m| f64::from(zf.data[i * 2 + m]) * f64::from(q.data[m * 3 + c]))
                .sum();
            assert_eq!(z.data[i * 3 + c], want as f32);
        }
    }
    // Receiver b reads block a (no basis) as stored, then block b through the basis.
    assert_eq!(entries[1].z.cols, 2 + 3);
    assert_eq!(entries[1].z.data[..2], f.entries[1].z.data[..2]);
}

#[test]
fn a_transport_kind_in_the_other_transport_section_is_refused() {
    let b = factored_bundle(&mut Lcg(6));
    let sections = b.raw_sections();
    let moved: Vec<(u32, Vec<u8>)> = sections
        .iter()
        .map(|(k, p)| match *k {
            section::TRANSPORT_SOURCE_BASES => (section::TRANSPORT, p.clone()),
            _ => (*k, p.clone()),
        })
        .collect();
    let e = Bundle::decode(&join_sections(&moved))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("transport section kind 4 holds the wrong transport kind"),
        "{e}"
    );

    let (unfolded, _) = b.unfold_source_bases();
    let moved: Vec<(u32, Vec<u8>)> = unfolded
        .raw_sections()
        .into_iter()
        .map(|(k, p)| match k {
            section::TRANSPORT => (section::TRANSPORT_SOURCE_BASES, p),
            _ => (k, p),
        })
        .collect();
    let e = Bundle::decode(&join_sections(&moved))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("transport section kind 16 holds the wrong transport kind"),
        "{e}"
    );
}

#[test]
fn two_transport_sections_are_refused_and_none_is_a_level_without_transport() {
    let b = factored_bundle(&mut Lcg(7));
    let sections = b.raw_sections();
    let (unfolded, _) = b.clone().unfold_source_bases();
    let kind4 = unfolded
        .raw_sections()
        .into_iter()
        .find(|(k, _)| *k == section::TRANSPORT)
        .unwrap();
    let mut both = sections.clone();
    both.insert(3, kind4);
    let e = Bundle::decode(&join_sections(&both))
        .unwrap_err()
        .to_string();
    assert!(e.contains("two transport sections"), "{e}");

    // Without section 16 (a reader that skips it sees this): the rest decodes, no transport.
    let skipped: Vec<(u32, Vec<u8>)> = sections
        .into_iter()
        .filter(|(k, _)| *k != section::TRANSPORT_SOURCE_BASES)
        .collect();
    let decoded = Bundle::decode(&join_sections(&skipped)).unwrap();
    assert_eq!(decoded.transport, None);
    assert_eq!(decoded.drt, b.drt);
}

#[test]
fn a_basis_of_the_wrong_size_is_refused_with_the_block_named() {
    let mut b = factored_bundle(&mut Lcg(8));
    let Some(TransportOps::Factored(f)) = &mut b.transport else {
        unreachable!()
    };
    f.bases[0].q.cols = 2;
    f.bases[0].q.data.truncate(4);
    let e = b.validate().unwrap_err().to_string();
    assert!(
        e.contains("source basis of block 1 is 2×2, the block's rank is 3"),
        "{e}"
    );
}

/// Relative RMS error of a decoded matrix against the original.
fn relative_error(
    got: &lightfarm_proto::bundle::Matrix,
    want: &lightfarm_proto::bundle::Matrix,
) -> f64 {
    let (mut d, mut n) = (0.0f64, 0.0f64);
    for (g, w) in got.data.iter().zip(&want.data) {
        d += (f64::from(*g) - f64::from(*w)).powi(2);
        n += f64::from(*w).powi(2);
    }
    (d / n).sqrt()
}

#[test]
fn bases_and_their_receivers_are_coded_within_their_shares_of_the_transport_budget() {
    use lightfarm_proto::bundle::EncodeOptions;
    use lightfarm_proto::codec::CodecPolicy;
    let b = factored_bundle(&mut Lcg(9));
    let budget = 0.04;
    let (bytes, _) = b.encode_with(&EncodeOptions {
        codec: CodecPolicy::Budget(0.2),
        transport_codec: Some(CodecPolicy::Budget(budget)),
        zstd_level: 3,
    });
    let decoded = Bundle::decode(&bytes).unwrap();
    let (Some(TransportOps::Factored(got)), Some(TransportOps::Factored(want))) =
        (&decoded.transport, &b.transport)
    else {
        panic!("kind 3 decodes as kind 3")
    };
    let mut coded = 0;
    for (g, w) in got.bases.iter().zip(&want.bases) {
        let e = relative_error(&g.q, &w.q);
        assert!(e <= 0.5 * budget, "basis of block {}: {e}", w.source_block);
        coded += usize::from(e > 0.0);
    }
    for (g, w) in got.entries.iter().zip(&want.entries) {
        let e = relative_error(&g.z, &w.z);
        assert!(e <= 0.75 * budget, "Z' of receiver {}: {e}", w.target_block);
        assert!(relative_error(&g.y, &w.y) <= budget);
        coded += usize::from(e > 0.0);
    }
    assert!(
        coded > 0,
        "some matrix was coded lossily, so the shares were tested"
    );
}
