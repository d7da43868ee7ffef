//! Tests of the per-frame runtime ([`super`]): hand-built bundles with known operators
//! (every method and transport kind against explicit matrix products), bounce modes against
//! hand-iterated series, no allocation per frame, bit-identical results at any thread count.
//!
//! # Layout
//! - this file: the allocation counter, the hand-built bundles (MRT with every transport kind,
//!   DRT, probes) and dense f64 references, and the tests of MRT, Full, argument errors, no
//!   allocation per frame, encode/decode round trips and inconsistent bundles.
//! - `drt`: DRT against its dense reference, `replaced` texels, DRT without entries or section.
//! - `probes`: `apply_probes` against a dense reference (defined there), its errors, round
//!   trip, inconsistent probe sections.
//! - `fuzz`: mutated and truncated encodings: whatever decodes makes a runtime that applies
//!   every method and the probes without a panic (the decoder's own properties are asserted in
//!   `proto/tests/decode_fuzz.rs`).
//! - `bounces`: `Fixed`, `Converged` and `Feedback` against hand-iterated series, refusal of a
//!   gain-one operator, bit-identical results at one and two threads.
//! - `reduced_drt`: DRT's `Converged` in coefficient space against the texel path and many
//!   bounces, its first-bounce energy, the texel path kept for what it does not model.
//! - `incremental`: `apply_delta` (relighting by the change of direct light) against applying
//!   the new light, the reach it follows, `Feedback` refused.

#![allow(clippy::needless_range_loop)]

use super::*;
use crate::probes::ProbeField;
use lightfarm_proto::bundle::{
    CompactEntry, DeltaSource, DrtOps, Matrix, SourceBases, SourceBasis, SparseRows, TexelGather,
};
use lightfarm_proto::testing::{
    allocs, blocks, drt_bundle, join_sections, layout, lightfield_transport, matrix, probe_bundle,
    random_full, shape, traced_transport, CountingAlloc, Lcg, N_PROBES,
};

mod bounces;
mod drt;
mod fuzz;
mod incremental;
mod probes;
mod reduced_drt;

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

/// Three blocks (shape 0: 4 texels, r = 2, openings +x (q = 3) and -z (q = 2); shape 1:
/// 11 texels, r = 3, opening -x (q = 2)), then 2 clutter texels.
fn bundle(rng: &mut Lcg, transport: Option<TransportOps>, full: bool) -> Bundle {
    let layout = layout(
        rng,
        &[
            ("block:a/+x", 4),
            ("block:b/-x", 11),
            ("block:c/+x", 4),
            ("clutter:box", 2),
        ],
    );
    let n = layout.n_texels();
    let shapes = vec![
        shape(rng, "s0", 4, 2, &[(1, 3), (4, 2)]),
        shape(rng, "s1", 11, 3, &[(0, 2)]),
    ];
    let blocks = blocks(&[("a", 0, 0), ("b", 1, 4), ("c", 0, 15)]);
    let full = full.then(|| random_full(rng, n));
    Bundle {
        layout,
        shapes,
        blocks,
        transport,
        full,
        ..Bundle::default()
    }
}

/// A coefficient-space `Converged` against the texel path's and many explicit bounces: both
/// within 5e-5 of the bounces, the coefficients in at most two applications more.
fn assert_reduced_matches(
    case: &str,
    (reduced, applied): (&IndirectLight, Applied),
    (texel, texel_applied): (&IndirectLight, Applied),
    many: &IndirectLight,
) {
    let (err, texel_err) = (
        crate::compare::relative_l2(&reduced.radiance, &many.radiance),
        crate::compare::relative_l2(&texel.radiance, &many.radiance),
    );
    assert!(
        err <= 5e-5 && texel_err <= 5e-5,
        "{case}: reduced {err}, texel {texel_err}"
    );
    assert!(
        applied.bounces <= texel_applied.bounces + 2,
        "{case}: {applied:?} against {texel_applied:?}"
    );
}

/// An exact gather whose row `rows[i]` reads the texels `reads[i]`, its values drawn from
/// `lo..hi`.
fn gather_rows(rng: &mut Lcg, rows: &[u32], reads: &[&[u32]], (lo, hi): (f32, f32)) -> TexelGather {
    let mut gather = TexelGather {
        rows: rows.to_vec(),
        row_start: vec![0],
        ..TexelGather::default()
    };
    for cols in reads {
        gather.cols.extend_from_slice(cols);
        gather.values.extend(cols.iter().map(|_| rng.range(lo, hi)));
        gather.row_start.push(gather.cols.len() as u32);
    }
    gather
}

/// Texels of the DRT test bundle ([`drt_bundle`]): blocks a (0..4) and b (4..10), clutter box
/// (10..14) and, with `two_clutter`, clutter lamp (14..17).
const DRT_BOX: std::ops::Range<usize> = 10..14;

/// Coefficient counts r and opening sizes q by block, as the test bundle has them.
const R: [usize; 3] = [2, 3, 2];

fn traced(rng: &mut Lcg) -> TransportOps {
    let pairs = [(1, 0), (0, 2), (0, 1), (2, 2), (0, 2)];
    traced_transport(rng, &pairs, &[4, 11, 4], &R)
}

/// Compact transport: blocks 0 and 2 receive (block 1 none); k = 2 and 3.
fn compact(rng: &mut Lcg) -> TransportOps {
    let texels = [4usize, 11, 4];
    let entries = [(0u32, vec![1u32, 2], 2usize), (2, vec![0, 1, 2], 3)];
    TransportOps::Compact(
        entries
            .iter()
            .map(|(t, sources, k)| {
                let width = sources.iter().map(|s| R[*s as usize]).sum();
                CompactEntry {
                    target_block: *t,
                    sources: sources.clone(),
                    y: matrix(rng, texels[*t as usize], *k),
                    z: matrix(rng, *k, width),
                }
            })
            .collect(),
    )
}

/// Compact transport with shared source bases: [`compact`]'s receivers, source 1 (r = 3) read
/// through a 2 × 3 basis and source 2 (r = 2) through a 1 × 2 one, source 0 as it is.
fn factored(rng: &mut Lcg) -> TransportOps {
    let texels = [4usize, 11, 4];
    let bases = vec![
        SourceBasis {
            source_block: 1,
            q: matrix(rng, 2, 3),
        },
        SourceBasis {
            source_block: 2,
            q: matrix(rng, 1, 2),
        },
    ];
    let width = [2usize, 2, 1];
    let entries = [(0u32, vec![1u32, 2], 2usize), (2, vec![0, 1, 2], 3)];
    TransportOps::Factored(SourceBases {
        bases,
        entries: entries
            .iter()
            .map(|(t, sources, k)| CompactEntry {
                target_block: *t,
                sources: sources.clone(),
                y: matrix(rng, texels[*t as usize], *k),
                z: matrix(rng, *k, sources.iter().map(|s| width[*s as usize]).sum()),
            })
            .collect(),
    })
}

fn lightfield(rng: &mut Lcg) -> TransportOps {
    // (target, face, q, source); two entries feed block a's +x opening.
    let entries = [
        (0, 1, 3, 1),
        (0, 4, 2, 2),
        (0, 1, 3, 2),
        (1, 0, 2, 0),
        (2, 1, 3, 0),
    ];
    lightfield_transport(rng, &entries, &R)
}

fn direct(rng: &mut Lcg, n: usize) -> DirectLight {
    DirectLight {
        radiance: (0..n)
            .map(|_| {
                [
                    rng.range(0.0, 2.0),
                    rng.range(0.0, 2.0),
                    rng.range(0.0, 2.0),
                ]
            })
            .collect(),
    }
}

fn get(m: &Matrix, i: usize, j: usize) -> f64 {
    m.data[i * m.cols as usize + j] as f64
}

/// `m · ld[offset .. offset + m.cols]` per channel, in f64.
fn reference_project(m: &Matrix, ld: &[[f32; 3]], offset: u32) -> Vec<[f64; 3]> {
    (0..m.rows as usize)
        .map(|j| {
            let mut v = [0.0; 3];
            for t in 0..m.cols as usize {
                for c in 0..3 {
                    v[c] += get(m, j, t) * ld[offset as usize + t][c] as f64;
                }
            }
            v
        })
        .collect()
}

/// Every block's coefficients b, in f64.
fn reference_coefs(bundle: &Bundle, ld: &[[f32; 3]]) -> Vec<Vec<[f64; 3]>> {
    bundle
        .blocks
        .iter()
        .map(|blk| {
            let s = &bundle.shapes[blk.shape as usize];
            reference_project(&s.t_db, ld, blk.texel_offset)
        })
        .collect()
}

fn times_albedo(bundle: &Bundle, mut out: Vec<[f64; 3]>) -> Vec<[f64; 3]> {
    for (o, rho) in out.iter_mut().zip(&bundle.layout.albedo) {
        for c in 0..3 {
            o[c] *= rho[c] as f64;
        }
    }
    out
}

/// `m · x` in f64, x three channels per column of `m`.
fn product(m: &Matrix, x: &[[f64; 3]]) -> Vec<[f64; 3]> {
    (0..m.rows as usize)
        .map(|k| {
            let mut v = [0.0; 3];
            for (j, x) in x.iter().enumerate() {
                for c in 0..3 {
                    v[c] += get(m, k, j) * x[c];
                }
            }
            v
        })
        .collect()
}

/// Straightforward dense MRT, in f64.
fn reference_mrt(bundle: &Bundle, ld: &[[f32; 3]]) -> Vec<[f64; 3]> {
    times_albedo(bundle, reference_mrt_albedo_free(bundle, ld))
}

/// Dense MRT before the albedo, in f64.
fn reference_mrt_albedo_free(bundle: &Bundle, ld: &[[f32; 3]]) -> Vec<[f64; 3]> {
    let shape = |bi: u32| &bundle.shapes[bundle.blocks[bi as usize].shape as usize];
    let coefs = reference_coefs(bundle, ld);
    let mut out = vec![[0.0f64; 3]; ld.len()];
    let mut add = |bi: u32, m: &Matrix, x: &[[f64; 3]]| {
        let off = bundle.blocks[bi as usize].texel_offset as usize;
        for t in 0..m.rows as usize {
            for j in 0..m.cols as usize {
                for c in 0..3 {
                    out[off + t][c] += get(m, t, j) * x[j][c];
                }
            }
        }
    };
    for (bi, x) in coefs.iter().enumerate() {
        add(bi as u32, &shape(bi as u32).u_b, x);
    }
    match &bundle.transport {
        Some(TransportOps::Traced(entries)) => {
            for e in entries {
                add(e.target_block, &e.matrix, &coefs[e.source_block as usize]);
            }
        }
        Some(TransportOps::Lightfield(entries)) => {
            for (bi, _) in bundle.blocks.iter().enumerate() {
                for o in &shape(bi as u32).openings {
                    let mut r = vec![[0.0f64; 3]; o.u_r.cols as usize];
                    for e in entries
                        .iter()
                        .filter(|e| e.target_block == bi as u32 && e.target_face == o.face)
                    {
                        for (k, rk) in r.iter_mut().enumerate() {
                            for j in 0..e.matrix.cols as usize {
                                for c in 0..3 {
                                    rk[c] +=
                                        get(&e.matrix, k, j) * coefs[e.source_block as usize][j][c];
                                }
                            }
                        }
                    }
                    add(bi as u32, &o.u_r, &r);
                }
            }
        }
        Some(TransportOps::Compact(entries)) => {
            for e in entries {
                let stacked: Vec<[f64; 3]> = e
                    .sources
                    .iter()
                    .flat_map(|s| coefs[*s as usize].iter().copied())
                    .collect();
                add(e.target_block, &e.y, &product(&e.z, &stacked));
            }
        }
        Some(TransportOps::Factored(f)) => {
            for e in &f.entries {
                // A source with a basis is read as Q · b (j values), the others as b.
                let stacked: Vec<[f64; 3]> = e
                    .sources
                    .iter()
                    .flat_map(|&s| {
                        let b = &coefs[s as usize];
                        match f.basis(s) {
                            Some(q) => product(q, b),
                            None => b.clone(),
                        }
                    })
                    .collect();
                add(e.target_block, &e.y, &product(&e.z, &stacked));
            }
        }
        None => {}
    }
    out
}

/// Straightforward dense DRT, in f64: every delta entry expanded into a dense
/// n_texels × (Σ r + Σ m) matrix D over the stacked coefficients `[b_0 … b_B, c_0 … c_J]`,
/// then `l_ind = ρ ⊙ (MRT_albedo_free + D · coefficients)`.
fn reference_drt(bundle: &Bundle, ld: &[[f32; 3]]) -> Vec<[f64; 3]> {
    let drt = bundle.drt.as_ref().unwrap();
    let n = ld.len();
    let mut coefs: Vec<[f64; 3]> = reference_coefs(bundle, ld).concat();
    let mut block_start = vec![0];
    for blk in &bundle.blocks {
        let r = bundle.shapes[blk.shape as usize].u_b.cols as usize;
        block_start.push(block_start.last().unwrap() + r);
    }
    let mut clutter_start = vec![coefs.len()];
    for cl in &drt.clutter {
        coefs.extend(reference_project(&cl.t_dc, ld, cl.texel_offset));
        clutter_start.push(coefs.len());
    }
    // Direct-light sources read the direct light itself, stacked after the coefficients.
    let direct_start = coefs.len();
    coefs.extend(ld.iter().map(|l| l.map(|v| v as f64)));
    let mut dense = vec![vec![0.0f64; coefs.len()]; n];
    for e in &drt.entries {
        let start = match e.source {
            DeltaSource::Block(k) => block_start[k as usize],
            DeltaSource::Clutter(j) => clutter_start[j as usize],
            DeltaSource::Direct { first, .. } => direct_start + first as usize,
        };
        // A low-rank entry's matrix is `matrix · mix`.
        let (cols, value): (usize, Box<dyn Fn(usize, usize) -> f64>) = match &e.mix {
            None => (
                e.matrix.cols as usize,
                Box::new(|i, j| get(&e.matrix, i, j)),
            ),
            Some(mix) => (
                mix.cols as usize,
                Box::new(move |i, j| {
                    (0..mix.rows as usize)
                        .map(|l| get(&e.matrix, i, l) * get(mix, l, j))
                        .sum()
                }),
            ),
        };
        for (i, &t) in e.rows.iter().enumerate() {
            for j in 0..cols {
                dense[t as usize][start + j] += value(i, j);
            }
        }
    }
    let mut out = reference_mrt_albedo_free(bundle, ld);
    for &x in &drt.replaced {
        out[x as usize] = [0.0; 3];
    }
    for (o, row) in out.iter_mut().zip(&dense) {
        for (d, x) in row.iter().zip(&coefs) {
            for c in 0..3 {
                o[c] += d * x[c];
            }
        }
    }
    times_albedo(bundle, out)
}

fn reference_full(bundle: &Bundle, ld: &[[f32; 3]]) -> Vec<[f64; 3]> {
    let f = bundle.full.as_ref().unwrap();
    (0..f.n as usize)
        .map(|i| {
            let mut v = [0.0f64; 3];
            for k in f.row_start[i] as usize..f.row_start[i + 1] as usize {
                for c in 0..3 {
                    v[c] += f.values[k] as f64 * ld[f.cols[k] as usize][c] as f64;
                }
            }
            for c in 0..3 {
                v[c] *= bundle.layout.albedo[i][c] as f64;
            }
            v
        })
        .collect()
}

fn assert_close(got: &IndirectLight, want: &[[f64; 3]]) {
    assert_eq!(got.radiance.len(), want.len());
    for (i, (g, w)) in got.radiance.iter().zip(want).enumerate() {
        for c in 0..3 {
            assert!(
                (g[c] as f64 - w[c]).abs() <= 1e-5 * (1.0 + w[c].abs()),
                "texel {i} channel {c}: {} vs {}",
                g[c],
                w[c]
            );
        }
    }
}

fn run(bundle: Bundle, method: Method, ld: &DirectLight) -> IndirectLight {
    let mut rt = Runtime::new(bundle);
    let mut out = IndirectLight::default();
    rt.apply(method, Bounces::One, ld, &mut out).unwrap();
    out
}

#[test]
fn mrt_with_traced_transport_matches_reference() {
    let mut rng = Lcg(11);
    let t = traced(&mut rng);
    let b = bundle(&mut rng, Some(t), false);
    let ld = direct(&mut rng, 21);
    let want = reference_mrt(&b, &ld.radiance);
    let got = run(b, Method::Mrt, &ld);
    assert_close(&got, &want);
    assert_eq!(
        &got.radiance[19..],
        &[[0.0; 3]; 2],
        "clutter texels get 0 under MRT"
    );
}

#[test]
fn mrt_with_compact_transport_matches_reference() {
    let mut rng = Lcg(13);
    let t = compact(&mut rng);
    let b = bundle(&mut rng, Some(t), false);
    let ld = direct(&mut rng, 21);
    let want = reference_mrt(&b, &ld.radiance);
    let got = run(b, Method::Mrt, &ld);
    assert_close(&got, &want);
}

/// Shared source bases: the runtime applies `Z'` and the bases as shipped, which is the kind-2
/// bundle they unfold to within float rounding.
#[test]
fn mrt_with_factored_transport_matches_its_unfolded_reference() {
    let mut rng = Lcg(15);
    let t = factored(&mut rng);
    let b = bundle(&mut rng, Some(t), false);
    let (unfolded, kept) = b.clone().unfold_source_bases();
    assert!(kept.is_some());
    assert!(matches!(unfolded.transport, Some(TransportOps::Compact(_))));
    unfolded
        .validate()
        .expect("the unfolded bundle is a valid kind-2 bundle");
    let ld = direct(&mut rng, 21);
    // The reference reads the factored form itself (Q · b, then Z'), not the unfolding.
    let want = reference_mrt(&b, &ld.radiance);
    assert_close(&run(b, Method::Mrt, &ld), &want);
    assert_close(&run(unfolded.clone(), Method::Mrt, &ld), &want);
    assert_close(
        &run(unfolded.clone(), Method::Mrt, &ld),
        &reference_mrt(&unfolded, &ld.radiance),
    );
}

#[test]
fn mrt_with_lightfield_transport_matches_reference() {
    let mut rng = Lcg(12);
    let t = lightfield(&mut rng);
    let b = bundle(&mut rng, Some(t), false);
    let ld = direct(&mut rng, 21);
    let want = reference_mrt(&b, &ld.radiance);
    // The transport really contributes (compare with no transport).
    let local = reference_mrt(
        &Bundle {
            transport: None,
            ..b.clone()
        },
        &ld.radiance,
    );
    assert!(want
        .iter()
        .zip(&local)
        .any(|(a, l)| (a[0] - l[0]).abs() > 1e-3));
    let got = run(b, Method::Mrt, &ld);
    assert_close(&got, &want);
    assert_eq!(&got.radiance[19..], &[[0.0; 3]; 2]);
}

#[test]
fn mrt_without_transport_is_local_only() {
    let mut rng = Lcg(13);
    let b = bundle(&mut rng, None, false);
    let ld = direct(&mut rng, 21);
    let want = reference_mrt(&b, &ld.radiance);
    assert_close(&run(b, Method::Mrt, &ld), &want);
}

#[test]
fn full_matches_reference() {
    let mut rng = Lcg(14);
    let t = traced(&mut rng);
    let b = bundle(&mut rng, Some(t), true);
    let ld = direct(&mut rng, 21);
    let want = reference_full(&b, &ld.radiance);
    let got = run(b, Method::Full, &ld);
    assert_close(&got, &want);
    assert!(
        got.radiance[19..].iter().flatten().any(|&v| v != 0.0),
        "clutter texels are lit under Full"
    );
}

#[test]
fn full_without_the_operator_is_an_error() {
    let mut rng = Lcg(15);
    let mut rt = Runtime::new(bundle(&mut rng, None, false));
    assert!(!rt.has_full());
    let ld = direct(&mut rng, 21);
    let mut out = IndirectLight::default();
    let err = rt
        .apply(Method::Full, Bounces::One, &ld, &mut out)
        .unwrap_err();
    assert_eq!(err, ApplyError::MissingFull);
    assert_eq!(
        err.to_string(),
        "this bundle has no dense operator; bake it with --full"
    );
}

#[test]
fn wrong_direct_length_is_an_error_not_a_panic() {
    let mut rng = Lcg(16);
    let t = lightfield(&mut rng);
    let mut rt = Runtime::new(bundle(&mut rng, Some(t), true));
    let mut out = IndirectLight::default();
    for len in [0, 20, 22] {
        let ld = direct(&mut rng, len);
        // Drt too: the length is checked before whether the bundle has the section.
        for method in [Method::Mrt, Method::Full, Method::Drt] {
            let err = rt.apply(method, Bounces::One, &ld, &mut out).unwrap_err();
            assert_eq!(
                err,
                ApplyError::DirectLength {
                    expected: 21,
                    got: len
                }
            );
        }
    }
}

#[test]
fn apply_twice_is_identical_and_does_not_allocate() {
    let mut rng = Lcg(17);
    let before = allocs();
    drop(std::hint::black_box(vec![1u8; 64]));
    assert!(allocs() > before, "the allocation counter works");
    let mrt_full: &[Method] = &[Method::Mrt, Method::Full];
    let all: &[Method] = &[Method::Mrt, Method::Full, Method::Drt];
    let (mrt_drt, mrt_only): (&[Method], &[Method]) = (&[Method::Mrt, Method::Drt], &[Method::Mrt]);
    let mut cases = Vec::new();
    for transport in [
        Some(traced(&mut rng)),
        Some(lightfield(&mut rng)),
        Some(compact(&mut rng)),
        None,
    ] {
        cases.push((bundle(&mut rng, transport, true), mrt_full));
    }
    for (lightfield, two_clutter) in [(false, false), (true, true)] {
        cases.push((drt_bundle(&mut rng, lightfield, two_clutter, true), all));
    }
    for drt in [false, true] {
        let methods = if drt { mrt_drt } else { mrt_only };
        cases.push((probe_bundle(&mut rng, drt), methods));
        // Low-rank probe entries (format 2.3) need scratch for `mix · x`: still none allocated.
        let low_rank = probes::low_rank_probe_bundle(&mut rng, drt, &[1, 3, 2]);
        cases.push((low_rank, methods));
    }
    for (b, methods) in cases {
        let n = b.layout.n_texels();
        let has_probes = b.probes.is_some();
        let mut rt = Runtime::new(b);
        let ld = direct(&mut rng, n);
        let mut firsts = Vec::new();
        for &method in methods {
            // A wrong-length `out` is resized; a right-length one is reused.
            let mut out = IndirectLight {
                radiance: vec![[9.0; 3]; 5],
            };
            rt.apply(method, Bounces::One, &ld, &mut out).unwrap();
            let first = out.clone();
            let before = allocs();
            rt.apply(method, Bounces::One, &ld, &mut out).unwrap();
            rt.apply(method, Bounces::One, &ld, &mut out).unwrap();
            assert_eq!(allocs(), before, "{method:?}: apply allocated");
            assert_eq!(out, first, "{method:?}: not deterministic");
            // Stale values in `out` do not leak into the result.
            out.radiance.fill([f32::NAN; 3]);
            rt.apply(method, Bounces::One, &ld, &mut out).unwrap();
            assert_eq!(out, first);
            firsts.push(first);
        }
        // Nor does one method's scratch leak into another's result.
        let mut out = IndirectLight::default();
        for (&method, first) in methods.iter().zip(&firsts).rev() {
            rt.apply(method, Bounces::One, &ld, &mut out).unwrap();
            assert_eq!(&out, first, "{method:?} after another method");
        }
        if !has_probes {
            continue;
        }
        // apply_probes: a wrong-size field is resized, a right-size one reused.
        let mut field = ProbeField::default();
        field.reset(3);
        rt.apply_probes(&ld, &mut field).unwrap();
        let first = field.clone();
        assert_eq!(first.n_probes(), N_PROBES);
        let before = allocs();
        rt.apply_probes(&ld, &mut field).unwrap();
        rt.apply_probes(&ld, &mut field).unwrap();
        assert_eq!(allocs(), before, "apply_probes allocated");
        assert_eq!(field, first, "apply_probes not deterministic");
        field.fill_for_test(f32::NAN);
        rt.apply_probes(&ld, &mut field).unwrap();
        assert_eq!(field, first, "stale values leak into apply_probes");
        // apply and apply_probes share scratch without changing each other's results.
        for (&method, first_out) in methods.iter().zip(&firsts) {
            rt.apply(method, Bounces::One, &ld, &mut out).unwrap();
            rt.apply_probes(&ld, &mut field).unwrap();
            assert_eq!(field, first, "apply_probes after {method:?}");
            rt.apply(method, Bounces::One, &ld, &mut out).unwrap();
            assert_eq!(&out, first_out, "{method:?} after apply_probes");
        }
        assert_eq!(allocs(), before, "apply or apply_probes allocated");
    }
}

#[test]
fn encode_decode_round_trip_gives_the_same_output() {
    let mut rng = Lcg(18);
    for transport in [
        traced(&mut rng),
        lightfield(&mut rng),
        compact(&mut rng),
        factored(&mut rng),
    ] {
        let b = bundle(&mut rng, Some(transport), true);
        let decoded = Bundle::decode(&b.encode()).expect("hand-built bundle decodes");
        assert_eq!(decoded, b);
        let ld = direct(&mut rng, 21);
        for method in [Method::Mrt, Method::Full] {
            assert_eq!(
                run(b.clone(), method, &ld),
                run(decoded.clone(), method, &ld)
            );
        }
    }
}

#[test]
fn drt_encode_decode_round_trip_gives_the_same_output() {
    let mut rng = Lcg(28);
    for (lightfield, two_clutter, full) in [(false, false, true), (true, true, false)] {
        let b = drt_bundle(&mut rng, lightfield, two_clutter, full);
        let decoded = Bundle::decode(&b.encode()).expect("hand-built DRT bundle decodes");
        assert_eq!(decoded, b);
        let ld = direct(&mut rng, b.layout.n_texels());
        let want = reference_drt(&b, &ld.radiance);
        let got = run(decoded.clone(), Method::Drt, &ld);
        assert_close(&got, &want);
        assert_eq!(got, run(b.clone(), Method::Drt, &ld));
        assert_eq!(run(decoded, Method::Mrt, &ld), run(b, Method::Mrt, &ld));
    }
}

#[test]
fn inconsistent_hand_built_bundles_are_refused() {
    let mut rng = Lcg(19);
    let t = lightfield(&mut rng);
    let good = bundle(&mut rng, Some(t), true);
    assert!(Runtime::try_new(good.clone()).is_ok());

    let mut b = good.clone();
    b.blocks[2].texel_offset = 18;
    assert!(Runtime::try_new(b).is_err(), "block past the layout");
    let mut b = good.clone();
    b.blocks[0].shape = 7;
    assert!(Runtime::try_new(b).is_err(), "missing shape");
    let mut b = good.clone();
    b.shapes[1].t_db.data.pop();
    assert!(Runtime::try_new(b).is_err(), "short matrix");
    let mut b = good.clone();
    if let Some(TransportOps::Lightfield(e)) = &mut b.transport {
        e[0].target_face = 5;
    }
    assert!(Runtime::try_new(b).is_err(), "opening the shape lacks");
    let mut b = good.clone();
    b.full.as_mut().unwrap().cols[0] = 21;
    assert!(Runtime::try_new(b).is_err(), "full column out of range");
    let mut b = good;
    b.layout.albedo.pop();
    assert!(Runtime::try_new(b).is_err(), "albedo length");
}

#[test]
fn inconsistent_drt_sections_are_refused_as_decode_refuses_them() {
    let mut rng = Lcg(29);
    let good = drt_bundle(&mut rng, true, true, false);
    assert!(Runtime::try_new(good.clone()).is_ok());
    type Break = (&'static str, fn(&mut DrtOps));
    let breaks: [Break; 14] = [
        ("clutter past the layout", |d| {
            d.clutter[1].texel_offset = 15
        }),
        ("short t_dc", |d| {
            d.clutter[0].t_dc.data.pop();
        }),
        ("missing source block", |d| {
            d.entries[0].source = DeltaSource::Block(2)
        }),
        ("missing source clutter", |d| {
            d.entries[2].source = DeltaSource::Clutter(2)
        }),
        ("source with another coefficient count", |d| {
            d.entries[2].source = DeltaSource::Clutter(1)
        }),
        ("block source with another r", |d| {
            d.entries[0].source = DeltaSource::Block(0)
        }),
        ("more rows than matrix rows", |d| d.entries[0].rows.push(12)),
        ("rows not ascending", |d| d.entries[0].rows.swap(0, 1)),
        ("repeated row", |d| d.entries[0].rows[1] = 1),
        ("row past the layout", |d| d.entries[6].rows[2] = 17),
        ("buried past the layout", |d| d.buried.push(17)),
        ("replaced not ascending", |d| d.replaced = vec![4, 1]),
        ("replaced on a clutter texel", |d| d.replaced = vec![10]),
        ("repeated replaced texel", |d| d.replaced = vec![2, 2]),
    ];
    fn drt_of(b: &mut Bundle) -> &mut DrtOps {
        b.drt.as_mut().unwrap()
    }
    assert_each_refused(&good, &breaks, drt_of);
}

/// Every break of `good` (each applied to the part `part` picks) is refused by the runtime and
/// by decode.
fn assert_each_refused<T>(
    good: &Bundle,
    breaks: &[(&'static str, fn(&mut T))],
    part: fn(&mut Bundle) -> &mut T,
) {
    for (what, f) in breaks {
        let mut b = good.clone();
        f(part(&mut b));
        assert!(
            Runtime::try_new(b.clone()).is_err(),
            "runtime accepts: {what}"
        );
        assert!(
            Bundle::decode(&b.encode()).is_err(),
            "decode accepts: {what}"
        );
    }
}
