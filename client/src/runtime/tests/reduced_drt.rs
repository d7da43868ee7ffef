//! Tests of [`Bounces::Converged`] for DRT in coefficient space (`runtime/reduced_drt.rs`):
//! the same light as the texel path's GMRES and as many explicit bounces wherever the system
//! is exact (no gather, a gather reading blocks, a gather reading a clutter object whose basis
//! spans its texels, a gather reading tiles of block texels, the gather in low-rank form), the first bounce's energy from coefficients equal to `One`'s, the texel
//! path kept for what it does not model, no allocation and the same bits on a second call and
//! at two threads.

use super::*;
use crate::compare::relative_l2;
use lightfarm_proto::bundle::DeltaEntry;

/// Clutter texels of [`drt_bundle`] with two clutter objects: the box (m = 2 < 4 texels) and
/// the lamp (m = 3 = its texels).
const BOX: std::ops::Range<usize> = 10..14;
const LAMP: std::ops::Range<usize> = 14..17;

/// [`drt_bundle`] (traced transport, box and lamp) without its delta entries over direct light,
/// each clutter object of one albedo, the lamp's basis orthonormal and spanning its texels, and
/// (if `reads` is not empty) an exact gather whose rows 10, 11, 13, 14 and 16 read `reads`.
pub(super) fn reducible(rng: &mut Lcg, reads: &[&[u32]]) -> Bundle {
    let mut b = drt_bundle(rng, false, true, false);
    for range in [BOX, LAMP] {
        let a = b.layout.albedo[range.start];
        b.layout.albedo[range].fill(a);
    }
    let d = b.drt.as_mut().unwrap();
    d.entries
        .retain(|e| !matches!(e.source, DeltaSource::Direct { .. }));
    // A rotation about the lamp's first texel: orthonormal, full rank.
    let (c, s) = (0.6f32, 0.8f32);
    d.clutter[1].t_dc = Matrix {
        rows: 3,
        cols: 3,
        data: vec![1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c],
    };
    if !reads.is_empty() {
        let mut gather = gather_rows(rng, &[10, 11, 13, 14, 16], reads, (0.05, 0.3));
        // Columns 17.. read the means of three tiles of block texels (format 2.6).
        for tile in [&[0, 1, 2][..], &[4, 5, 6], &[7, 8, 9]] {
            gather.tiles.push(tile);
        }
        d.direct_gather = Some(gather);
    }
    b
}

/// Reads of blocks alone, and of blocks and the lamp (whose basis spans its texels).
const BLOCK_READS: [&[u32]; 5] = [&[0, 2], &[3, 4, 9], &[5, 6], &[1, 8], &[7]];
pub(super) const LAMP_READS: [&[u32]; 5] =
    [&[0, 14, 15], &[3, 16], &[5, 6, 14], &[1, 15], &[16, 2]];
/// Reads of blocks, the lamp and the tiles of block texels (columns 17, 18, 19).
const TILE_READS: [&[u32]; 5] = [&[0, 17], &[3, 18], &[5, 14, 19], &[1, 17, 18], &[16, 19]];

/// A runtime for `b` with the albedo halved until the texel path's `Converged` converges
/// (random operators may keep more light than they receive).
fn converging(mut b: Bundle, ld: &DirectLight) -> Runtime {
    for _ in 0..8 {
        let mut rt = Runtime::new(b.clone());
        rt.ungate_reduced_drt();
        rt.set_reduced_bounces(false);
        let mut out = IndirectLight::default();
        let tolerance = Bounces::Converged { tolerance: 1e-5 };
        if rt.apply(Method::Drt, tolerance, ld, &mut out).is_ok() {
            rt.set_reduced_bounces(true);
            return rt;
        }
        b.layout.albedo.iter_mut().flatten().for_each(|a| *a *= 0.5);
    }
    panic!("the test bundle's light never converged");
}

/// `b` with the exact gather's low-rank form too: entries over the light of block a's texels
/// (rows on the box, `mix`) and of the lamp's (rows on the box and the lamp, dense).
fn with_low_rank_gather(rng: &mut Lcg, mut b: Bundle) -> Bundle {
    let d = b.drt.as_mut().unwrap();
    d.entries.push(DeltaEntry {
        matrix: matrix(rng, 2, 2),
        rows: vec![10, 12],
        source: DeltaSource::Direct { first: 0, count: 4 },
        mix: Some(matrix(rng, 2, 4)),
    });
    d.entries.push(DeltaEntry {
        matrix: matrix(rng, 3, 3),
        rows: vec![11, 13, 15],
        source: DeltaSource::Direct {
            first: 14,
            count: 3,
        },
        mix: None,
    });
    b
}

#[test]
fn reduced_drt_matches_the_texel_path_and_many_bounces_where_exact() {
    let mut rng = Lcg(83);
    for (reads, low_rank, case) in [
        (&[][..], false, "no gather"),
        (&BLOCK_READS[..], false, "gather reading blocks"),
        (&LAMP_READS[..], false, "gather reading blocks and the lamp"),
        (&[][..], true, "low-rank gather alone"),
        (&LAMP_READS[..], true, "gather and low-rank gather"),
        (&TILE_READS[..], false, "gather reading tiles"),
    ] {
        let mut b = reducible(&mut rng, reads);
        if low_rank {
            b = with_low_rank_gather(&mut rng, b);
        }
        let ld = direct(&mut rng, b.layout.n_texels());
        let mut rt = converging(b, &ld);
        let tolerance = Bounces::Converged { tolerance: 1e-5 };
        let (mut reduced, mut texel, mut many) = Default::default();
        let applied = rt.apply(Method::Drt, tolerance, &ld, &mut reduced).unwrap();
        assert!(
            rt.reduced_drt_first_energy().is_some(),
            "{case}: the texel path solved"
        );
        rt.set_reduced_bounces(false);
        let texel_applied = rt.apply(Method::Drt, tolerance, &ld, &mut texel).unwrap();
        rt.apply(Method::Drt, Bounces::Fixed(400), &ld, &mut many)
            .unwrap();
        assert_reduced_matches(case, (&reduced, applied), (&texel, texel_applied), &many);
        // The first bounce's energy, made from coefficients, is that of one bounce.
        let mut one = IndirectLight::default();
        rt.apply(Method::Drt, Bounces::One, &ld, &mut one).unwrap();
        let e1 = rt.reduced_drt_first_energy().unwrap();
        for c in 0..3 {
            let want = one.radiance.iter().map(|x| x[c] as f64).sum::<f64>();
            assert!(
                (e1[c] - want).abs() <= 1e-4 * want.abs().max(1e-9),
                "{case}: channel {c}: {} against {want}",
                e1[c]
            );
        }
        // The right-hand side's other way (views or the gather itself) gives the same light.
        rt.set_reduced_bounces(true);
        if reads.len() + usize::from(low_rank) > 0 {
            assert!(rt.switch_reduced_drt_rhs());
            let mut other = IndirectLight::default();
            rt.apply(Method::Drt, tolerance, &ld, &mut other).unwrap();
            let diff = relative_l2(&other.radiance, &reduced.radiance);
            assert!(
                diff <= 1e-6,
                "{case}: the two right-hand sides differ by {diff}"
            );
            rt.switch_reduced_drt_rhs();
        }
        // A second solve allocates nothing and repeats the same bits.
        let first = reduced.clone();
        let before = allocs();
        rt.apply(Method::Drt, tolerance, &ld, &mut reduced).unwrap();
        assert_eq!(allocs(), before, "{case}: the second solve allocated");
        assert_eq!(reduced, first, "{case}: not deterministic");
    }
}

/// A gather reading the box, whose basis (m = 2) does not span its 4 texels: its bounced light
/// there is the basis's implied light, so the answer differs from the texel path's, by a small
/// fraction of the bounces after the first (2e-4 of all the light here, against their 0.52;
/// the maze's clutter texels 3.4e-5).
#[test]
fn reduced_drt_reading_clutter_outside_its_basis_stays_close() {
    let mut rng = Lcg(89);
    let reads: [&[u32]; 5] = [&[0, 12], &[3, 13], &[5, 10, 14], &[1, 11], &[16, 2]];
    let b = reducible(&mut rng, &reads);
    let ld = direct(&mut rng, b.layout.n_texels());
    let mut rt = converging(b, &ld);
    let tolerance = Bounces::Converged { tolerance: 1e-6 };
    let (mut reduced, mut texel, mut one) = Default::default();
    rt.apply(Method::Drt, tolerance, &ld, &mut reduced).unwrap();
    assert!(rt.reduced_drt_first_energy().is_some());
    rt.set_reduced_bounces(false);
    rt.apply(Method::Drt, tolerance, &ld, &mut texel).unwrap();
    rt.apply(Method::Drt, Bounces::One, &ld, &mut one).unwrap();
    let err = relative_l2(&reduced.radiance, &texel.radiance);
    // The bounces after the first are what the approximation touches: the error is a fraction
    // of their light, not of the first bounce's.
    let later: Vec<[f32; 3]> = texel
        .radiance
        .iter()
        .zip(&one.radiance)
        .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
        .collect();
    let norm = |v: &[[f32; 3]]| v.iter().flatten().map(|x| (*x as f64).powi(2)).sum::<f64>();
    let later_share = (norm(&later) / norm(&texel.radiance)).sqrt();
    assert!(
        err > 0.0 && err < 0.02 * later_share,
        "{err} against the later bounces' share {later_share}"
    );
}

#[test]
fn what_reduced_drt_does_not_model_keeps_the_texel_path() {
    let mut rng = Lcg(91);
    // Its entries over direct light have a row on a block texel (a scene gather's).
    let with_direct = drt_bundle(&mut rng, false, true, false);
    let lightfield = {
        let mut b = drt_bundle(&mut rng, true, true, false);
        b.drt
            .as_mut()
            .unwrap()
            .entries
            .retain(|e| !matches!(e.source, DeltaSource::Direct { .. }));
        b
    };
    let replaced = {
        let mut b = reducible(&mut rng, &[]);
        b.drt.as_mut().unwrap().replaced = vec![0, 5];
        b
    };
    let two_albedos = {
        let mut b = reducible(&mut rng, &BLOCK_READS);
        b.layout.albedo[11] = [0.3, 0.2, 0.1];
        b
    };
    for (b, case) in [
        (with_direct, "an entry over the light with a row on a block"),
        (lightfield, "lightfield transport"),
        (replaced, "replaced texels"),
        (two_albedos, "a gathering clutter object of two albedos"),
    ] {
        let ld = direct(&mut rng, b.layout.n_texels());
        let mut rt = Runtime::new(b);
        rt.ungate_reduced_drt();
        let mut out = IndirectLight::default();
        let _ = rt.apply(Method::Drt, Bounces::default(), &ld, &mut out);
        assert!(rt.reduced_drt_first_energy().is_none(), "{case}");
    }
}

/// The tiny test bundle's coefficient space reads about as many values per application as its
/// texels: the gate keeps the texel path there (the maze's reads 0.23 of them, grid1000's 0.76).
#[test]
fn the_gate_keeps_the_texel_path_where_coefficients_read_as_many_values() {
    let mut rng = Lcg(95);
    let b = reducible(&mut rng, &LAMP_READS);
    let ld = direct(&mut rng, b.layout.n_texels());
    let b = converging(b, &ld).bundle().clone();
    for gated in [true, false] {
        let mut rt = Runtime::new(b.clone());
        if !gated {
            rt.ungate_reduced_drt();
        }
        let mut out = IndirectLight::default();
        rt.apply(Method::Drt, Bounces::default(), &ld, &mut out)
            .unwrap();
        assert_eq!(rt.reduced_drt_first_energy().is_none(), gated);
    }
}

#[cfg(feature = "rayon")]
#[test]
fn reduced_drt_is_bit_identical_at_one_and_two_threads() {
    let mut rng = Lcg(93);
    let b = reducible(&mut rng, &LAMP_READS);
    let ld = direct(&mut rng, b.layout.n_texels());
    let b = converging(b, &ld).bundle().clone();
    let mut outputs = Vec::new();
    for threads in [1usize, 2] {
        let (pool, mut rt) = super::bounces::runtime_on(threads, &b);
        rt.ungate_reduced_drt();
        let mut out = IndirectLight::default();
        pool.install(|| rt.apply(Method::Drt, Bounces::default(), &ld, &mut out))
            .unwrap();
        assert!(rt.reduced_drt_first_energy().is_some());
        outputs.push(out);
    }
    assert_eq!(outputs[0], outputs[1]);
}
