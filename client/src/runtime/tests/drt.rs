//! Tests of `Method::Drt` (`runtime/drt.rs`): the hand-built DRT bundles of [`super`] against
//! the dense f64 reference (one or two clutter objects, traced or lightfield transport),
//! `replaced` texels and their minor-3 section, DRT without entries or without the section.

use super::*;

#[test]
fn drt_matches_dense_reference() {
    let mut rng = Lcg(21);
    for (lightfield, two_clutter) in [(false, false), (true, false), (false, true), (true, true)] {
        let b = drt_bundle(&mut rng, lightfield, two_clutter, false);
        let n = b.layout.n_texels();
        let ld = direct(&mut rng, n);
        let want = reference_drt(&b, &ld.radiance);
        let mrt = reference_mrt(&b, &ld.radiance);
        let got = run(b, Method::Drt, &ld);
        assert_close(&got, &want);
        // The entries really contribute: block texels differ from MRT, clutter is lit.
        assert!(want[..10]
            .iter()
            .zip(&mrt)
            .any(|(d, m)| (d[0] - m[0]).abs() > 1e-3));
        for t in 10..n {
            assert!(
                got.radiance[t].iter().all(|&v| v != 0.0),
                "clutter texel {t}"
            );
        }
    }
}

#[test]
fn replaced_texels_keep_only_their_drt_terms_and_travel_in_the_minor_3_section() {
    use lightfarm_proto::bundle::section;
    let mut rng = Lcg(37);
    let mut b = drt_bundle(&mut rng, false, true, false);
    b.drt.as_mut().unwrap().replaced = vec![1, 4, 7];
    let n = b.layout.n_texels();
    let ld = direct(&mut rng, n);
    let want = reference_drt(&b, &ld.radiance);
    let got = run(b.clone(), Method::Drt, &ld);
    assert_close(&got, &want);
    // A replaced texel keeps exactly its DRT terms: DRT without the list, minus MRT.
    let mrt = run(b.clone(), Method::Mrt, &ld);
    let mut kept = b.clone();
    kept.drt.as_mut().unwrap().replaced.clear();
    let drt = run(kept, Method::Drt, &ld);
    for x in [1, 4, 7] {
        assert!(mrt.radiance[x].iter().all(|v| v.abs() > 1e-3));
        for c in 0..3 {
            let want = drt.radiance[x][c] - mrt.radiance[x][c];
            assert!((got.radiance[x][c] - want).abs() < 1e-5, "texel {x}");
        }
    }
    // The section is kind 23 and round-trips; a reader that does not know kind 23 skips
    // it and lights the scene by MRT alone (never MRT plus the gather).
    let sections = b.raw_sections();
    assert!(sections
        .iter()
        .any(|(k, _)| *k == section::DRT_MODELLED_GATHER));
    let decoded = Bundle::decode(&b.encode()).expect("decodes");
    assert_eq!(decoded, b);
    let older: Vec<(u32, Vec<u8>)> = sections
        .into_iter()
        .filter(|(k, _)| *k != section::DRT_MODELLED_GATHER)
        .collect();
    let older = Bundle::decode(&join_sections(&older)).expect("decodes without DRT");
    assert!(older.drt.is_none());
}

#[test]
fn drt_without_entries_is_mrt_and_leaves_clutter_dark() {
    let mut rng = Lcg(22);
    for lightfield in [false, true] {
        let mut b = drt_bundle(&mut rng, lightfield, true, false);
        b.drt.as_mut().unwrap().entries.clear();
        let n = b.layout.n_texels();
        let ld = direct(&mut rng, n);
        let mut rt = Runtime::new(b);
        let (mut drt, mut mrt) = (IndirectLight::default(), IndirectLight::default());
        rt.apply(Method::Drt, Bounces::One, &ld, &mut drt).unwrap();
        rt.apply(Method::Mrt, Bounces::One, &ld, &mut mrt).unwrap();
        assert_eq!(drt.radiance[..10], mrt.radiance[..10], "block texels");
        assert!(drt.radiance[..10].iter().flatten().any(|&v| v != 0.0));
        assert!(
            drt.radiance[DRT_BOX.start..]
                .iter()
                .flatten()
                .all(|&v| v == 0.0),
            "clutter texels get only what entries add"
        );
    }
}

#[test]
fn drt_without_the_section_is_an_error() {
    let mut rng = Lcg(23);
    let t = traced(&mut rng);
    let mut rt = Runtime::new(bundle(&mut rng, Some(t), true));
    assert!(!rt.has_drt());
    let ld = direct(&mut rng, 21);
    let mut out = IndirectLight::default();
    let err = rt
        .apply(Method::Drt, Bounces::One, &ld, &mut out)
        .unwrap_err();
    assert_eq!(err, ApplyError::MissingDrt);
    assert_eq!(
        err.to_string(),
        "this bundle has no DRT operators; bake a scene with clutter"
    );
    assert!(Runtime::new(drt_bundle(&mut rng, false, false, false)).has_drt());
}
