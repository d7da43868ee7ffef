//! Tests of `Runtime::apply_probes` and `Runtime::apply_probes_delta` (`runtime/probes.rs`): the
//! probe bundles of [`super`] against a dense f64 reference of the probe field (here), fields
//! made by the change against the new light's, the errors, the encode/decode round trip and
//! probe sections `validate` refuses as `decode` does.

use super::*;
use crate::probes::irradiance_at;

/// Straightforward dense probe field, in f64: every probe entry expanded into a dense
/// (n_probes · 9) × (Σ r + Σ m) matrix over the stacked `[b_0 … b_B, c_0 … c_J]`, times
/// those coefficients. Indexed `[probe · 9 + coefficient][channel]`.
fn reference_probes(bundle: &Bundle, ld: &[[f32; 3]]) -> Vec<[f64; 3]> {
    let probes = bundle.probes.as_ref().unwrap();
    let mut coefs: Vec<[f64; 3]> = reference_coefs(bundle, ld).concat();
    let mut block_start = vec![0];
    for blk in &bundle.blocks {
        let r = bundle.shapes[blk.shape as usize].u_b.cols as usize;
        block_start.push(block_start.last().unwrap() + r);
    }
    let mut clutter_start = vec![coefs.len()];
    for cl in bundle.drt.iter().flat_map(|d| &d.clutter) {
        coefs.extend(reference_project(&cl.t_dc, ld, cl.texel_offset));
        clutter_start.push(coefs.len());
    }
    let n_rows = probes.n_probes as usize * 9;
    let mut dense = vec![vec![0.0f64; coefs.len()]; n_rows];
    for e in &probes.entries {
        let start = match e.source {
            DeltaSource::Block(k) => block_start[k as usize],
            DeltaSource::Clutter(j) => clutter_start[j as usize],
            DeltaSource::Direct { .. } => unreachable!("probe entries have no direct source"),
        };
        for (i, &t) in e.rows.iter().enumerate() {
            match &e.mix {
                None => {
                    for j in 0..e.matrix.cols as usize {
                        dense[t as usize][start + j] += get(&e.matrix, i, j);
                    }
                }
                // Low rank: row i of `matrix · mix`.
                Some(mix) => {
                    for j in 0..mix.cols as usize {
                        dense[t as usize][start + j] += (0..mix.rows as usize)
                            .map(|k| get(&e.matrix, i, k) * get(mix, k, j))
                            .sum::<f64>();
                    }
                }
            }
        }
    }
    dense
        .iter()
        .map(|row| {
            let mut v = [0.0f64; 3];
            for (d, x) in row.iter().zip(&coefs) {
                for c in 0..3 {
                    v[c] += d * x[c];
                }
            }
            v
        })
        .collect()
}

/// A way to break a probe bundle, named.
type Break = (&'static str, fn(&mut Bundle));

/// The whole bundle, the part a probe break changes.
fn whole(b: &mut Bundle) -> &mut Bundle {
    b
}

fn run_probes(bundle: Bundle, ld: &DirectLight) -> ProbeField {
    let mut rt = Runtime::new(bundle);
    let mut out = ProbeField::default();
    rt.apply_probes(ld, &mut out).unwrap();
    out
}

fn assert_probes_close(got: &ProbeField, want: &[[f64; 3]]) {
    assert_eq!(got.n_probes() * 9, want.len());
    for (row, w) in want.iter().enumerate() {
        for c in 0..3 {
            let g = got.coefficients(row / 9, c)[row % 9] as f64;
            assert!(
                (g - w[c]).abs() <= 1e-5 * (1.0 + w[c].abs()),
                "probe {} coefficient {} channel {c}: {g} vs {}",
                row / 9,
                row % 9,
                w[c]
            );
        }
    }
}

#[test]
fn probes_match_dense_reference() {
    let mut rng = Lcg(31);
    for drt in [true, false] {
        let b = probe_bundle(&mut rng, drt);
        let ld = direct(&mut rng, b.layout.n_texels());
        let want = reference_probes(&b, &ld.radiance);
        let volume = b.probes.clone().unwrap();
        let got = run_probes(b.clone(), &ld);
        assert_probes_close(&got, &want);
        // Every probe but 5 is fed (its coefficients stay exactly 0); the clutter entries
        // really contribute.
        for p in 0..N_PROBES {
            let zero = (0..3).all(|c| got.coefficients(p, c).iter().all(|&v| v == 0.0));
            assert_eq!(zero, p == 5, "probe {p}");
        }
        if drt {
            let mut blocks_only = b;
            let p = blocks_only.probes.as_mut().unwrap();
            p.entries
                .retain(|e| matches!(e.source, DeltaSource::Block(_)));
            let without = reference_probes(&blocks_only, &ld.radiance);
            assert!(want
                .iter()
                .zip(&without)
                .any(|(a, w)| (a[0] - w[0]).abs() > 1e-3));
        }
        // At a probe's grid point, irradiance_at gives that probe's own irradiance.
        for (i, &s) in volume.slot.iter().enumerate() {
            if s == u32::MAX {
                continue;
            }
            let g = [i & 1, i >> 1 & 1, i >> 2].map(|x| x as f32);
            let pos: [f32; 3] = std::array::from_fn(|a| volume.origin[a] + 0.5 * g[a]);
            let n = [0.6f32, 0.0, 0.8];
            // Normalised as irradiance_at does it (0.6f32, 0.8f32 are not exactly unit).
            let len = n.iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt();
            let unit = n.map(|x| x as f64 / len);
            let want: [f32; 3] = std::array::from_fn(|c| {
                let l = got.coefficients(s as usize, c).map(|v| v as f64);
                lightfarm_proto::sh::irradiance(&l, unit).max(0.0) as f32
            });
            assert_eq!(irradiance_at(&volume, &got, pos, n), want, "probe {s}");
        }
    }
}

/// `probe_bundle` with every entry of `ranks.len()` (cycled) made low-rank: `matrix` (rows × k)
/// times `mix` (k × the source's width), random.
pub(super) fn low_rank_probe_bundle(rng: &mut Lcg, drt: bool, ranks: &[usize]) -> Bundle {
    let mut b = probe_bundle(rng, drt);
    for (e, &k) in b
        .probes
        .as_mut()
        .unwrap()
        .entries
        .iter_mut()
        .zip(ranks.iter().cycle())
    {
        let cols = e.matrix.cols as usize;
        e.mix = Some(lightfarm_proto::testing::matrix(rng, k, cols));
        e.matrix = lightfarm_proto::testing::matrix(rng, e.rows.len(), k);
    }
    b
}

/// Low-rank probe entries (format 2.3): the runtime applies `matrix · (mix · x)` as the dense
/// f64 reference of the product does; such a volume is written as section kind 17 and decodes
/// to itself, and a dense one is still kind 7; a `mix` whose size does not fit is refused.
#[test]
fn low_rank_probe_entries_match_the_dense_reference() {
    use lightfarm_proto::bundle::section;
    use lightfarm_proto::container::read_sections;
    let kinds_of = |bytes: &[u8]| -> Vec<u32> {
        let sections = read_sections(bytes, 2..=2, |_| true, false)
            .unwrap()
            .sections;
        sections.iter().map(|(kind, _)| *kind).collect()
    };
    let mut rng = Lcg(36);
    for drt in [true, false] {
        let b = low_rank_probe_bundle(&mut rng, drt, &[1, 3, 2]);
        let ld = direct(&mut rng, b.layout.n_texels());
        let want = reference_probes(&b, &ld.radiance);
        let got = run_probes(b.clone(), &ld);
        assert_probes_close(&got, &want);
        assert!(
            want.iter().any(|w| w[0].abs() > 1e-3),
            "the entries feed the probes"
        );

        let bytes = b.encode();
        let kinds = kinds_of(&bytes);
        assert!(kinds.contains(&section::PROBES_LOW_RANK) && !kinds.contains(&section::PROBES));
        let decoded = Bundle::decode(&bytes).expect("low-rank probe bundle decodes");
        assert_eq!(decoded, b);
        assert_eq!(run_probes(decoded, &ld), got);
        let dense = probe_bundle(&mut rng, drt).encode();
        let kinds = kinds_of(&dense);
        assert!(kinds.contains(&section::PROBES) && !kinds.contains(&section::PROBES_LOW_RANK));
    }
    let good = low_rank_probe_bundle(&mut rng, true, &[2]);
    let breaks: [Break; 3] = [
        ("mix narrower than the source", |b| {
            let e = &mut b.probes.as_mut().unwrap().entries[0];
            let mix = e.mix.as_mut().unwrap();
            mix.cols -= 1;
            mix.data.truncate((mix.rows * mix.cols) as usize);
        }),
        ("matrix wider than the mix's rows", |b| {
            let e = &mut b.probes.as_mut().unwrap().entries[1];
            e.matrix.cols += 1;
            e.matrix
                .data
                .resize((e.matrix.rows * e.matrix.cols) as usize, 0.0);
        }),
        ("short mix", |b| {
            let e = &mut b.probes.as_mut().unwrap().entries[2];
            e.mix.as_mut().unwrap().data.pop();
        }),
    ];
    assert_each_refused(&good, &breaks, whole);
}

/// A field made by the change is the new light's within float rounding, whatever the entries
/// (dense or low rank, with or without clutter, a block no entry reads), and with relighting by
/// the change between the calls (both share the sparse scratch); a change on texels no entry
/// reads leaves the field as it was, bit for bit; a field of another size is refused and left
/// as it was.
#[test]
fn probes_by_the_change_equal_the_new_lights() {
    let mut rng = Lcg(37);
    let mut bundles = Vec::new();
    for drt in [true, false] {
        bundles.push(probe_bundle(&mut rng, drt));
        bundles.push(low_rank_probe_bundle(&mut rng, drt, &[1, 2]));
    }
    // Block 1 read by no entry: its texels are no source. With block 0 and the box, the
    // sources hold 8 of the 14 texels (`apply_probes` copies the whole light); with block 0
    // alone, 4 (it copies the sources' texels alone).
    for keep_clutter in [true, false] {
        let mut unread = probe_bundle(&mut rng, true);
        let p = unread.probes.as_mut().unwrap();
        p.entries.retain(|e| match e.source {
            DeltaSource::Block(k) => k == 0,
            _ => keep_clutter,
        });
        bundles.push(unread);
    }
    let mut moved = 0;
    for (case, b) in bundles.into_iter().enumerate() {
        let n = b.layout.n_texels();
        let block_1 = {
            let first = b.blocks[1].texel_offset as usize;
            first..first + b.shapes[b.blocks[1].shape as usize].u_b.rows as usize
        };
        let reads_block_1 = b
            .probes
            .as_ref()
            .unwrap()
            .entries
            .iter()
            .any(|e| matches!(e.source, DeltaSource::Block(1)));
        let mut rt = Runtime::new(b.clone());
        let mut fresh = Runtime::new(b.clone());
        // The texels probes read (blocks a 0..4 and b 4..10, the box 10..14).
        let read: &[(usize, usize)] = match case {
            0 | 1 => &[(0, 14)],
            2 | 3 => &[(0, 10)],
            4 => &[(0, 4), (10, 14)],
            _ => &[(0, 4)],
        };
        let spans: Vec<(usize, usize)> = rt
            .probe_source_spans()
            .iter()
            .map(|r| (r.start, r.end))
            .collect();
        assert_eq!(spans, read, "case {case}");
        let old = direct(&mut rng, n);
        let mut field = ProbeField::default();
        rt.apply_probes(&old, &mut field).unwrap();
        let mut indirect = IndirectLight::default();
        let method = if rt.has_drt() {
            Method::Drt
        } else {
            Method::Mrt
        };
        rt.apply(method, Bounces::One, &old, &mut indirect).unwrap();
        let mut light = old.clone();
        let mut last_want = field.clone();
        // Three changes in a row: block 1's texels, a run across blocks, nothing but zeros.
        let spans = [block_1.clone(), n / 3..n - 2, 0..n];
        for (step, span) in spans.iter().enumerate() {
            let mut change = DirectLight {
                radiance: vec![[0.0; 3]; n],
            };
            if step < 2 {
                for t in span.clone() {
                    change.radiance[t] = [rng.range(-0.5, 0.5), rng.range(-0.5, 0.5), 0.25];
                    for ch in 0..3 {
                        light.radiance[t][ch] += change.radiance[t][ch];
                    }
                }
            }
            // Relighting by the change first, as a game does, then the probes.
            rt.apply_delta_in(
                method,
                Bounces::One,
                &change,
                std::slice::from_ref(span),
                &mut indirect,
            )
            .unwrap();
            let before = field.clone();
            rt.apply_probes_delta(&change, std::slice::from_ref(span), &mut field)
                .unwrap();
            let mut want = ProbeField::default();
            fresh.apply_probes(&light, &mut want).unwrap();
            assert_probes_close(&want, &reference_probes(&b, &light.radiance));
            let scale = want.as_slice().iter().fold(0.0f32, |m, v| m.max(v.abs()));
            for (i, (g, w)) in field.as_slice().iter().zip(want.as_slice()).enumerate() {
                assert!(
                    (g - w).abs() <= 1e-5 * scale,
                    "case {case} step {step} value {i}: {g} by the change, {w} of the new light"
                );
            }
            // The field moves exactly when the new light's does (a change on texels no
            // entry reads, or of zeros, leaves it as it was, bit for bit).
            assert_eq!(
                field == before,
                want == last_want,
                "case {case} step {step}: the field by the change moved as the new light's did"
            );
            assert!(
                step != 2 || field == before,
                "case {case}: zeros changed the field"
            );
            assert!(step != 0 || reads_block_1 || field == before, "case {case}");
            moved += usize::from(field != before);
            last_want = want;
            // The indirect light by the change is still the new light's.
            let mut whole = IndirectLight::default();
            fresh
                .apply(method, Bounces::One, &light, &mut whole)
                .unwrap();
            for (a, w) in indirect.radiance.iter().zip(&whole.radiance) {
                for ch in 0..3 {
                    assert!(
                        (a[ch] - w[ch]).abs() <= 1e-4 * (1.0 + w[ch].abs()),
                        "case {case}"
                    );
                }
            }
        }
        // A field of another size is refused and left as it was.
        let mut other = ProbeField::default();
        let err = rt
            .apply_probes_delta(&old, std::slice::from_ref(&(0..n)), &mut other)
            .unwrap_err();
        assert_eq!(
            err,
            ApplyError::ProbeFieldSize {
                expected: N_PROBES,
                got: 0
            }
        );
        assert!(err.to_string().contains("apply_probes"), "{err}");
        assert_eq!(other.n_probes(), 0);
        let short = direct(&mut rng, n - 1);
        let kept = field.clone();
        assert!(matches!(
            rt.apply_probes_delta(&short, std::slice::from_ref(&(0..n - 1)), &mut field),
            Err(ApplyError::DirectLength { .. })
        ));
        assert_eq!(field, kept);
    }
    // Both changes moved the field of each of the first four bundles at least.
    assert!(moved >= 8, "{moved} changes moved a field");
}

#[test]
fn probes_without_the_section_are_an_error() {
    let mut rng = Lcg(32);
    let mut rt = Runtime::new(drt_bundle(&mut rng, true, true, false));
    assert!(!rt.has_probes() && rt.probe_volume().is_none());
    assert!(rt.probe_source_spans().is_empty());
    let n = rt.n_texels();
    let mut field = ProbeField::default();
    let err = rt
        .apply_probes(&direct(&mut rng, n), &mut field)
        .unwrap_err();
    assert_eq!(err, ApplyError::MissingProbes);
    assert_eq!(err.to_string(), "this bundle has no probe volume");
    // The direct light's length is checked first.
    let err = rt
        .apply_probes(&direct(&mut rng, n + 1), &mut field)
        .unwrap_err();
    assert_eq!(
        err,
        ApplyError::DirectLength {
            expected: n,
            got: n + 1
        }
    );
    let mut rt = Runtime::new(probe_bundle(&mut rng, true));
    assert!(rt.has_probes() && rt.probe_volume().is_some());
    let err = rt
        .apply_probes(&direct(&mut rng, n - 1), &mut field)
        .unwrap_err();
    assert!(matches!(err, ApplyError::DirectLength { .. }));
}

#[test]
fn probe_encode_decode_round_trip_gives_the_same_output() {
    let mut rng = Lcg(33);
    for drt in [true, false] {
        let b = probe_bundle(&mut rng, drt);
        let decoded = Bundle::decode(&b.encode()).expect("hand-built probe bundle decodes");
        assert_eq!(decoded, b);
        let ld = direct(&mut rng, b.layout.n_texels());
        let got = run_probes(decoded.clone(), &ld);
        assert_eq!(got, run_probes(b.clone(), &ld));
        assert_probes_close(&got, &reference_probes(&b, &ld.radiance));
        for method in [Method::Mrt, Method::Drt]
            .into_iter()
            .take(1 + drt as usize)
        {
            assert_eq!(
                run(decoded.clone(), method, &ld),
                run(b.clone(), method, &ld)
            );
        }
    }
}

#[test]
fn inconsistent_probe_sections_are_refused_as_decode_refuses_them() {
    let mut rng = Lcg(34);
    let good = probe_bundle(&mut rng, true);
    assert!(Runtime::try_new(good.clone()).is_ok());
    fn p(b: &mut Bundle) -> &mut ProbeVolume {
        b.probes.as_mut().unwrap()
    }
    let breaks: [Break; 18] = [
        ("zero spacing", |b| p(b).spacing = 0.0),
        ("negative spacing", |b| p(b).spacing = -0.5),
        ("NaN spacing", |b| p(b).spacing = f32::NAN),
        ("infinite origin", |b| p(b).origin[1] = f32::INFINITY),
        ("slot missing", |b| {
            p(b).slot.pop();
        }),
        ("dims past the slots", |b| p(b).dims[0] = 3),
        ("zero dims", |b| p(b).dims = [0, 2, 2]),
        ("more probes than grid points", |b| p(b).n_probes = 9),
        ("slot names a missing probe", |b| p(b).slot[3] = 7),
        ("missing source block", |b| {
            p(b).entries[1].source = DeltaSource::Block(2)
        }),
        ("missing source clutter", |b| {
            p(b).entries[2].source = DeltaSource::Clutter(1)
        }),
        ("clutter source without a DRT section", |b| b.drt = None),
        ("block source with another r", |b| {
            p(b).entries[0].source = DeltaSource::Block(1)
        }),
        ("more rows than matrix rows", |b| {
            p(b).entries[0].rows.push(9)
        }),
        ("rows not ascending", |b| p(b).entries[1].rows.swap(0, 1)),
        ("repeated row", |b| p(b).entries[1].rows[1] = 2),
        ("row past the probes", |b| p(b).entries[1].rows[5] = 63),
        ("short matrix", |b| {
            p(b).entries[3].matrix.data.pop();
        }),
    ];
    assert_each_refused(&good, &breaks, whole);
    // Grid sizes whose product overflows u64 (2^66 wraps to 0 = the slot count).
    let mut b = good.clone();
    p(&mut b).dims = [1 << 22; 3];
    p(&mut b).slot.clear();
    p(&mut b).n_probes = 0;
    p(&mut b).entries.clear();
    assert!(
        Runtime::try_new(b).is_err(),
        "runtime accepts overflowing dims"
    );
}

/// `Bundle::validate` multiplies the three probe dims in u64: 2^66 panics in debug builds
/// (and wraps to 0 in release, accepting a grid that does not match its slots).
#[test]
fn decode_refuses_overflowing_probe_dims() {
    let mut rng = Lcg(35);
    let mut b = probe_bundle(&mut rng, false);
    let p = b.probes.as_mut().unwrap();
    p.dims = [1 << 22; 3];
    p.slot.clear();
    p.n_probes = 0;
    p.entries.clear();
    assert!(Bundle::decode(&b.encode()).is_err());
}
