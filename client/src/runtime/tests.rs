//! Tests of the per-frame runtime ([`super`]): hand-built bundles with known operators
//! (every method and transport kind against explicit matrix products), bounce modes against
//! hand-iterated series, no allocation per frame, bit-identical results at any thread count.

#![allow(clippy::needless_range_loop)]

use super::*;
use crate::occluders::tests::Lcg;
use crate::probes::irradiance_at;
use lightfarm_proto::bundle::{
    BlockOps, ClutterOps, CompactEntry, DeltaEntry, DrtOps, Layout, Matrix, OpeningOps, PropEntry,
    ShapeOps, SparseRows, SurfaceInfo, TracedEntry,
};
use lightfarm_proto::bundle::{BUNDLE_MAJOR, BUNDLE_MINOR};
use lightfarm_proto::container::write_container;
use std::alloc::{GlobalAlloc, Layout as AllocLayout, System};
use std::cell::Cell;

/// Counts allocations made by the current thread (tests run on separate threads).
struct CountingAlloc;

thread_local! {
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: AllocLayout) -> *mut u8 {
        let _ = ALLOCS.try_with(|a| a.set(a.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: AllocLayout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: AllocLayout, new_size: usize) -> *mut u8 {
        let _ = ALLOCS.try_with(|a| a.set(a.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

fn allocs() -> u64 {
    ALLOCS.with(|a| a.get())
}

fn matrix(rng: &mut Lcg, rows: usize, cols: usize) -> Matrix {
    Matrix {
        rows: rows as u32,
        cols: cols as u32,
        data: (0..rows * cols).map(|_| rng.range(-1.0, 1.0)).collect(),
    }
}

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
        ShapeOps {
            key: "s0".into(),
            u_b: matrix(rng, 4, 2),
            t_db: matrix(rng, 2, 4),
            openings: vec![
                OpeningOps {
                    face: 1,
                    u_r: matrix(rng, 4, 3),
                },
                OpeningOps {
                    face: 4,
                    u_r: matrix(rng, 4, 2),
                },
            ],
        },
        ShapeOps {
            key: "s1".into(),
            u_b: matrix(rng, 11, 3),
            t_db: matrix(rng, 3, 11),
            openings: vec![OpeningOps {
                face: 0,
                u_r: matrix(rng, 11, 2),
            }],
        },
    ];
    let blocks = vec![
        BlockOps {
            symmetry: None,
            id: "a".into(),
            shape: 0,
            texel_offset: 0,
        },
        BlockOps {
            symmetry: None,
            id: "b".into(),
            shape: 1,
            texel_offset: 4,
        },
        BlockOps {
            symmetry: None,
            id: "c".into(),
            shape: 0,
            texel_offset: 15,
        },
    ];
    let full = full.then(|| random_full(rng, n));
    Bundle {
        layout,
        shapes,
        blocks,
        transport,
        full,
        drt: None,
        probes: None,
        dnrt: None,
        sh: None,
        surface_atlases: Vec::new(),
    }
}

/// A random sparse n × n dense-bounce operator (about a third of the entries set).
fn random_full(rng: &mut Lcg, n: usize) -> SparseRows {
    let mut f = SparseRows {
        n: n as u32,
        row_start: vec![0],
        cols: vec![],
        values: vec![],
    };
    for _ in 0..n {
        for c in 0..n as u32 {
            if rng.next_u32().is_multiple_of(3) {
                f.cols.push(c);
                f.values.push(rng.range(0.0, 0.1));
            }
        }
        f.row_start.push(f.cols.len() as u32);
    }
    f
}

fn layout(rng: &mut Lcg, surfaces: &[(&str, usize)]) -> Layout {
    let mut next = 0;
    let surfaces: Vec<SurfaceInfo> = surfaces
        .iter()
        .map(|&(name, count)| {
            next += count;
            SurfaceInfo {
                name: name.into(),
                texel_offset: (next - count) as u32,
                texel_count: count as u32,
            }
        })
        .collect();
    let n = next;
    Layout {
        scene_name: "hand-built".into(),
        surfaces,
        positions: (0..n).map(|i| [i as f32, 0.0, 0.0]).collect(),
        normals: vec![[0.0, 0.0, 1.0]; n],
        texel_size: vec![[0.5, 0.5]; n],
        albedo: (0..n)
            .map(|_| {
                [
                    rng.range(0.1, 0.9),
                    rng.range(0.1, 0.9),
                    rng.range(0.1, 0.9),
                ]
            })
            .collect(),
        rects: vec![],
        triangles: vec![],
    }
}

/// Texels of the DRT test bundle: blocks a (0..4) and b (4..10), clutter box (10..14) and,
/// with `two_clutter`, clutter lamp (14..17).
const DRT_BOX: std::ops::Range<usize> = 10..14;

/// Two blocks (a: shape 0, 4 texels, r = 2, opening +x (q = 3); b: shape 1, 6 texels,
/// r = 3, opening -x (q = 2)) with traced or lightfield transport between them, one clutter
/// object (box: 4 texels, m = 2) or two (plus lamp: 3 texels, m = 3), and delta entries of
/// all four kinds: block rows from a block, block rows from clutter, clutter rows from a
/// block, clutter rows from clutter (plus a self-entry, an empty one and overlapping rows).
fn drt_bundle(rng: &mut Lcg, lightfield: bool, two_clutter: bool, full: bool) -> Bundle {
    let mut surfaces = vec![("block:a/+x", 4), ("block:b/-x", 6), ("clutter:box", 4)];
    if two_clutter {
        surfaces.push(("clutter:lamp", 3));
    }
    let layout = layout(rng, &surfaces);
    let n = layout.n_texels();
    let shapes = vec![
        ShapeOps {
            key: "s0".into(),
            u_b: matrix(rng, 4, 2),
            t_db: matrix(rng, 2, 4),
            openings: vec![OpeningOps {
                face: 1,
                u_r: matrix(rng, 4, 3),
            }],
        },
        ShapeOps {
            key: "s1".into(),
            u_b: matrix(rng, 6, 3),
            t_db: matrix(rng, 3, 6),
            openings: vec![OpeningOps {
                face: 0,
                u_r: matrix(rng, 6, 2),
            }],
        },
    ];
    let blocks = vec![
        BlockOps {
            symmetry: None,
            id: "a".into(),
            shape: 0,
            texel_offset: 0,
        },
        BlockOps {
            symmetry: None,
            id: "b".into(),
            shape: 1,
            texel_offset: 4,
        },
    ];
    let r = [2usize, 3];
    let transport = if lightfield {
        // (target, face, q, source)
        let entries = [(0u32, 1u8, 3usize, 1u32), (1, 0, 2, 0), (1, 0, 2, 1)];
        TransportOps::Lightfield(
            entries
                .iter()
                .map(|&(t, face, q, s)| PropEntry {
                    target_block: t,
                    target_face: face,
                    source_block: s,
                    matrix: matrix(rng, q, r[s as usize]),
                })
                .collect(),
        )
    } else {
        let texels = [4usize, 6];
        TransportOps::Traced(
            [(0u32, 1u32), (1, 0), (1, 1)]
                .iter()
                .map(|&(t, s)| TracedEntry {
                    target_block: t,
                    source_block: s,
                    matrix: matrix(rng, texels[t as usize], r[s as usize]),
                })
                .collect(),
        )
    };
    let mut clutter = vec![ClutterOps {
        id: "box".into(),
        texel_offset: 10,
        t_dc: matrix(rng, 2, 4),
    }];
    let m = [2usize, 3];
    let mut entries: Vec<(Vec<u32>, DeltaSource)> = vec![
        // Block rows (in both blocks) from a block: delta occlusion.
        (vec![1, 3, 6, 9], DeltaSource::Block(1)),
        (vec![0, 1, 2, 3], DeltaSource::Block(0)),
        // Block rows from clutter: delta reflection.
        (vec![0, 2, 5, 7], DeltaSource::Clutter(0)),
        // Clutter rows from a block: clutter gather.
        (vec![10, 11, 13], DeltaSource::Block(0)),
        // Clutter rows from clutter (its own): bounce, overlapping the gather's rows.
        (vec![10, 11, 12, 13], DeltaSource::Clutter(0)),
        (vec![], DeltaSource::Clutter(0)),
    ];
    if two_clutter {
        clutter.push(ClutterOps {
            id: "lamp".into(),
            texel_offset: 14,
            t_dc: matrix(rng, 3, 3),
        });
        entries.extend([
            (vec![14, 15, 16], DeltaSource::Clutter(1)),
            (vec![12], DeltaSource::Clutter(1)),
            (vec![4, 8], DeltaSource::Clutter(1)),
            (vec![14, 16], DeltaSource::Block(1)),
            (vec![15], DeltaSource::Clutter(0)),
        ]);
    }
    let entries = entries
        .into_iter()
        .map(|(rows, source)| {
            let cols = match source {
                DeltaSource::Block(k) => r[k as usize],
                DeltaSource::Clutter(j) => m[j as usize],
                DeltaSource::Direct { count, .. } => count as usize,
            };
            DeltaEntry {
                matrix: matrix(rng, rows.len(), cols),
                rows,
                source,
                mix: None,
            }
        })
        .collect::<Vec<_>>();
    // Low-rank entries (`mix`) and direct-light sources (the exact gather in low-rank form).
    let mut entries = entries;
    entries.extend([
        DeltaEntry {
            matrix: matrix(rng, 3, 2),
            rows: vec![4, 5, 6],
            source: DeltaSource::Block(1),
            mix: Some(matrix(rng, 2, r[1])),
        },
        DeltaEntry {
            matrix: matrix(rng, 2, 1),
            rows: vec![10, 12],
            source: DeltaSource::Direct { first: 0, count: 5 },
            mix: Some(matrix(rng, 1, 5)),
        },
        DeltaEntry {
            matrix: matrix(rng, 3, 4),
            rows: vec![1, 11, 13],
            source: DeltaSource::Direct { first: 6, count: 4 },
            mix: None,
        },
    ]);
    let full = full.then(|| random_full(rng, n));
    Bundle {
        layout,
        shapes,
        blocks,
        transport: Some(transport),
        full,
        drt: Some(DrtOps {
            clutter,
            entries,
            buried: vec![3, 12],
            direct_gather: None,
            replaced: Vec::new(),
        }),
        probes: None,
        dnrt: None,
        sh: None,
        surface_atlases: Vec::new(),
    }
}

/// Probes of the probe test bundle; probe 5 (rows 45..54) is fed by no entry.
const N_PROBES: usize = 7;

/// [`drt_bundle`] (blocks a, b; clutter box) with a 2×2×2 probe volume whose grid point
/// (1, 1, 0) is empty (7 probes), and probe entries from both blocks and (with `drt`) the
/// clutter object, overlapping rows, an empty entry and the last row. Without `drt` the
/// bundle has no DRT section and no clutter-sourced probe entries.
fn probe_bundle(rng: &mut Lcg, drt: bool) -> Bundle {
    let mut b = drt_bundle(rng, !drt, false, false);
    let mut entries: Vec<(Vec<u32>, DeltaSource)> = vec![
        ((0..9).collect(), DeltaSource::Block(0)),
        (vec![2, 9, 10, 20, 35, 62], DeltaSource::Block(1)),
        (vec![0, 4, 13, 27, 40, 54, 61], DeltaSource::Clutter(0)),
        (vec![18, 19, 26, 36, 44], DeltaSource::Block(0)),
        (vec![], DeltaSource::Clutter(0)),
        (vec![1, 62], DeltaSource::Clutter(0)),
    ];
    if !drt {
        b.drt = None;
        entries[4].1 = DeltaSource::Block(1);
        entries.retain(|(_, s)| matches!(s, DeltaSource::Block(_)));
    }
    let (r, m) = ([2usize, 3], 2usize);
    let entries = entries
        .into_iter()
        .map(|(rows, source)| DeltaEntry {
            matrix: matrix(
                rng,
                rows.len(),
                match source {
                    DeltaSource::Block(k) => r[k as usize],
                    DeltaSource::Clutter(_) => m,
                    DeltaSource::Direct { count, .. } => count as usize,
                },
            ),
            rows,
            source,
            mix: None,
        })
        .collect();
    b.probes = Some(ProbeVolume {
        origin: [0.25, 0.5, -1.0],
        spacing: 0.5,
        dims: [2, 2, 2],
        slot: vec![0, 1, 2, u32::MAX, 3, 4, 5, 6],
        n_probes: N_PROBES as u32,
        entries,
    });
    b
}

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
            for j in 0..e.matrix.cols as usize {
                dense[t as usize][start + j] += get(&e.matrix, i, j);
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

/// Coefficient counts r and opening sizes q by block, as the test bundle has them.
const R: [usize; 3] = [2, 3, 2];

fn traced(rng: &mut Lcg) -> TransportOps {
    let texels = [4usize, 11, 4];
    let pairs = [(1u32, 0u32), (0, 2), (0, 1), (2, 2), (0, 2)];
    TransportOps::Traced(
        pairs
            .iter()
            .map(|&(t, s)| TracedEntry {
                target_block: t,
                source_block: s,
                matrix: matrix(rng, texels[t as usize], R[s as usize]),
            })
            .collect(),
    )
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

fn lightfield(rng: &mut Lcg) -> TransportOps {
    // (target, face, q, source); two entries feed block a's +x opening.
    let entries = [
        (0u32, 1u8, 3usize, 1u32),
        (0, 4, 2, 2),
        (0, 1, 3, 2),
        (1, 0, 2, 0),
        (2, 1, 3, 0),
    ];
    TransportOps::Lightfield(
        entries
            .iter()
            .map(|&(t, face, q, s)| PropEntry {
                target_block: t,
                target_face: face,
                source_block: s,
                matrix: matrix(rng, q, R[s as usize]),
            })
            .collect(),
    )
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
                let z: Vec<[f64; 3]> = (0..e.z.rows as usize)
                    .map(|k| {
                        let mut v = [0.0; 3];
                        for (j, x) in stacked.iter().enumerate() {
                            for c in 0..3 {
                                v[c] += get(&e.z, k, j) * x[c];
                            }
                        }
                        v
                    })
                    .collect();
                add(e.target_block, &e.y, &z);
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
    for transport in [traced(&mut rng), lightfield(&mut rng), compact(&mut rng)] {
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
    for (what, f) in breaks {
        let mut b = good.clone();
        f(b.drt.as_mut().unwrap());
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
    // The section is kind 13 and round-trips; a reader that does not know kind 13 skips
    // it and lights the scene by MRT alone (never MRT plus the gather).
    let sections = b.raw_sections();
    assert!(sections.iter().any(|(k, _)| *k == section::DRT_REPLACING));
    let decoded = Bundle::decode(&b.encode()).expect("decodes");
    assert_eq!(decoded, b);
    let older: Vec<(u32, Vec<u8>)> = sections
        .into_iter()
        .filter(|(k, _)| *k != section::DRT_REPLACING)
        .collect();
    let older = Bundle::decode(&join_sections(&older)).expect("decodes without DRT");
    assert!(older.drt.is_none());
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

#[test]
fn probes_without_the_section_are_an_error() {
    let mut rng = Lcg(32);
    let mut rt = Runtime::new(drt_bundle(&mut rng, true, true, false));
    assert!(!rt.has_probes() && rt.probe_volume().is_none());
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
    type Break = (&'static str, fn(&mut Bundle));
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
    for (what, f) in breaks {
        let mut b = good.clone();
        f(&mut b);
        assert!(
            Runtime::try_new(b.clone()).is_err(),
            "runtime accepts: {what}"
        );
        assert!(
            Bundle::decode(&b.encode()).is_err(),
            "decode accepts: {what}"
        );
    }
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

/// A container of raw (uncompressed) sections, with fresh lengths, checksums and table of
/// contents, so edits inside a payload reach the bundle's validation.
fn join_sections(sections: &[(u32, Vec<u8>)]) -> Vec<u8> {
    write_container(BUNDLE_MAJOR, BUNDLE_MINOR, sections, 0).0
}

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
/// kind `focus`: none may panic (decode, runtime, apply, apply_probes, irradiance_at).
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
    // Truncations of the file.
    for _ in 0..500 {
        let len = rng.next_u32() as usize % bytes.len();
        assert!(!decode_and_apply(&bytes[..len]), "truncated to {len}");
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
    // Some repaired mutations (a changed value) still decode; many are refused.
    assert!(
        decoded > 0 && decoded < tried,
        "{decoded} of {tried} decoded"
    );
}

// ---- Bounces -------------------------------------------------------------------------

/// `Σ_{k=1..n} A^k ld` in f64 with `one` the dense one-bounce reference of the method.
fn reference_bounces(
    bundle: &Bundle,
    ld: &[[f32; 3]],
    n: u32,
    one: fn(&Bundle, &[[f32; 3]]) -> Vec<[f64; 3]>,
) -> Vec<[f64; 3]> {
    let mut light: Vec<[f32; 3]> = ld.to_vec();
    let mut sum = vec![[0.0f64; 3]; ld.len()];
    for _ in 0..n {
        let next = one(bundle, &light);
        for (s, v) in sum.iter_mut().zip(&next) {
            for c in 0..3 {
                s[c] += v[c];
            }
        }
        light = next.iter().map(|v| v.map(|x| x as f32)).collect();
    }
    sum
}

/// A bundle whose one-bounce gain is about `gain` for every method: every operator value is
/// scaled so the dense operator's largest row sum times the largest albedo is `gain`.
fn with_gain(mut b: Bundle, gain: f32) -> Bundle {
    let f = b.full.as_mut().expect("a full operator");
    let n = f.n as usize;
    let row_max = (0..n)
        .map(|i| {
            f.values[f.row_start[i] as usize..f.row_start[i + 1] as usize]
                .iter()
                .sum::<f32>()
        })
        .fold(0.0f32, f32::max);
    let rho_max = b
        .layout
        .albedo
        .iter()
        .flatten()
        .fold(0.0f32, |m, &x| m.max(x));
    let scale = gain / (row_max * rho_max);
    for v in &mut f.values {
        *v *= scale;
    }
    b
}

#[test]
fn fixed_bounces_equal_the_sum_of_explicit_bounces() {
    let mut rng = Lcg(41);
    // MRT (traced and lightfield transport), DRT and the dense operator, against f64
    // references iterated by hand.
    let (t, l) = (traced(&mut rng), lightfield(&mut rng));
    let cases: Vec<(Bundle, Method, fn(&Bundle, &[[f32; 3]]) -> Vec<[f64; 3]>)> = vec![
        (bundle(&mut rng, Some(t), false), Method::Mrt, reference_mrt),
        (bundle(&mut rng, Some(l), false), Method::Mrt, reference_mrt),
        (
            drt_bundle(&mut rng, true, true, false),
            Method::Drt,
            reference_drt,
        ),
        (
            with_gain(bundle(&mut rng, None, true), 0.7),
            Method::Full,
            reference_full,
        ),
    ];
    for (b, method, one) in cases {
        let n = b.layout.n_texels();
        let ld = direct(&mut rng, n);
        let mut rt = Runtime::new(b.clone());
        let mut out = IndirectLight::default();
        for bounces in [1u32, 2, 4] {
            let mode = if bounces == 1 {
                Bounces::One
            } else {
                Bounces::Fixed(bounces)
            };
            let applied = rt.apply(method, mode, &ld, &mut out).unwrap();
            assert_eq!(applied.bounces, bounces, "{method:?}");
            let want = reference_bounces(&b, &ld.radiance, bounces, one);
            // Relative to the largest value: the iterated random operators grow.
            let scale = want.iter().flatten().fold(1.0f64, |m, &x| m.max(x.abs()));
            for (g, w) in out.radiance.iter().zip(&want) {
                for c in 0..3 {
                    assert!(
                        (g[c] as f64 - w[c]).abs() <= 2e-5 * scale,
                        "{method:?} {bounces} bounces: {} vs {}",
                        g[c],
                        w[c]
                    );
                }
            }
        }
        assert_eq!(
            rt.apply(method, Bounces::Fixed(0), &ld, &mut out),
            Err(ApplyError::NoBounces)
        );
    }
}

/// Relative L2 of `a` against `b` over every texel and channel.
fn rel_l2(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        for c in 0..3 {
            num += (x[c] as f64 - y[c] as f64).powi(2);
            den += (y[c] as f64).powi(2);
        }
    }
    (num / den).sqrt()
}

#[test]
fn converged_matches_the_sum_of_many_bounces_within_its_tolerance_in_fewer_applications() {
    let mut rng = Lcg(43);
    for (b, method, gain) in [
        (
            with_gain(bundle(&mut rng, None, true), 0.6),
            Method::Full,
            0.6,
        ),
        (
            with_gain(bundle(&mut rng, None, true), 0.9),
            Method::Full,
            0.9,
        ),
    ] {
        let ld = direct(&mut rng, b.layout.n_texels());
        let mut rt = Runtime::new(b);
        let mut converged = IndirectLight::default();
        let mut many = IndirectLight::default();
        rt.apply(method, Bounces::Fixed(400), &ld, &mut many)
            .unwrap();
        let e_all = energy(&many.radiance);
        let mut previous = 0;
        for tolerance in [1e-2f32, 1e-3, 1e-5] {
            let applied = rt
                .apply(
                    method,
                    Bounces::Converged { tolerance },
                    &ld,
                    &mut converged,
                )
                .unwrap();
            assert!(applied.remaining_fraction <= tolerance, "{applied:?}");
            assert!(applied.bounces >= previous, "{applied:?}");
            previous = applied.bounces;
            let err = rel_l2(&converged.radiance, &many.radiance);
            let rest = (e_all - energy(&converged.radiance)).abs() / e_all;
            assert!(
                err <= 3.0 * tolerance as f64 + 1e-5 && rest <= 3.0 * tolerance as f64 + 1e-5,
                "gain {gain}, tolerance {tolerance}: relative L2 {err}, energy {rest}"
            );
            // Summing bounces one by one to the same error takes about
            // log(tolerance · (1 − λ)) / log(λ) bounces; GMRES needs at most half.
            let series = ((tolerance as f64 * (1.0 - gain)).ln() / gain.ln()).ceil() as u32;
            assert!(
                applied.bounces * 2 <= series,
                "gain {gain}, tolerance {tolerance}: {} applications vs {series} bounces",
                applied.bounces
            );
        }
    }
    let mut rng = Lcg(44);
    let b = with_gain(bundle(&mut rng, None, true), 0.6);
    let ld = direct(&mut rng, b.layout.n_texels());
    let mut rt = Runtime::new(b);
    let mut out = IndirectLight::default();
    for bad in [0.0f32, 1.0, -1.0, f32::NAN] {
        assert!(matches!(
            rt.apply(
                Method::Full,
                Bounces::Converged { tolerance: bad },
                &ld,
                &mut out
            ),
            Err(ApplyError::BadTolerance(_))
        ));
    }
}

#[test]
fn converged_equals_many_explicit_bounces_for_mrt_and_drt() {
    let mut rng = Lcg(45);
    let (t, l) = (traced(&mut rng), lightfield(&mut rng));
    for (b, method) in [
        (bundle(&mut rng, Some(t), false), Method::Mrt),
        (bundle(&mut rng, Some(l), false), Method::Mrt),
        (drt_bundle(&mut rng, true, true, false), Method::Drt),
    ] {
        let ld = direct(&mut rng, b.layout.n_texels());
        let mut rt = Runtime::new(b);
        let (mut converged, mut many) = (IndirectLight::default(), IndirectLight::default());
        match rt.apply(
            method,
            Bounces::Converged { tolerance: 1e-4 },
            &ld,
            &mut converged,
        ) {
            Ok(applied) => {
                rt.apply(method, Bounces::Fixed(300), &ld, &mut many)
                    .unwrap();
                let err = rel_l2(&converged.radiance, &many.radiance);
                assert!(err <= 5e-4, "{method:?}: {err} after {applied:?}");
            }
            // The random operators may have gain ≥ 1 (no all-bounce light): refused.
            Err(ApplyError::NotConverging { .. }) => {}
            Err(e) => panic!("{method:?}: {e}"),
        }
    }
}

#[test]
fn an_operator_with_gain_one_is_refused_not_looped_and_never_nan() {
    let mut rng = Lcg(47);
    for gain in [1.0f32, 1.5, 0.9999] {
        // A perfect reflector (albedo 1) whose every row sums to `gain`: the operator's
        // gain is exactly `gain`, like a closed white room.
        let mut b = bundle(&mut rng, None, true);
        let f = b.full.as_mut().unwrap();
        let mut rows = SparseRows {
            n: f.n,
            row_start: vec![0],
            cols: vec![],
            values: vec![],
        };
        for i in 0..f.n as usize {
            let (s, e) = (f.row_start[i] as usize, f.row_start[i + 1] as usize);
            let sum: f32 = f.values[s..e].iter().sum();
            if sum > 0.0 {
                rows.cols.extend_from_slice(&f.cols[s..e]);
                rows.values
                    .extend(f.values[s..e].iter().map(|v| v * gain / sum));
            } else {
                rows.cols.push(i as u32);
                rows.values.push(gain);
            }
            rows.row_start.push(rows.cols.len() as u32);
        }
        *f = rows;
        b.layout.albedo.fill([1.0; 3]);
        let ld = direct(&mut rng, b.layout.n_texels());
        let mut rt = Runtime::new(b);
        let mut out = IndirectLight::default();
        let err = rt
            .apply(Method::Full, Bounces::default(), &ld, &mut out)
            .unwrap_err();
        match err {
            ApplyError::NotConverging { bounces, .. } => {
                assert!(bounces <= MAX_BOUNCES, "{bounces}")
            }
            ApplyError::NonFinite { .. } => {}
            other => panic!("gain {gain}: {other}"),
        }
        assert!(err.to_string().contains("bounces"), "{err}");
        assert!(out.radiance.iter().flatten().all(|&x| x == 0.0));
    }
}

#[test]
fn feedback_converges_to_converged_and_stays_bounded_while_lights_move() {
    let mut rng = Lcg(53);
    for (b, method) in [
        (with_gain(bundle(&mut rng, None, true), 0.65), Method::Full),
        (drt_bundle(&mut rng, false, true, false), Method::Drt),
    ] {
        let n = b.layout.n_texels();
        let ld = direct(&mut rng, n);
        let mut rt = Runtime::new(b);
        let tight = Bounces::Converged { tolerance: 1e-6 };
        let mut converged = IndirectLight::default();
        if rt.apply(method, tight, &ld, &mut converged).is_err() {
            // The random DRT operators may have gain ≥ 1; then feedback is not defined
            // either. The dense case always runs.
            assert_eq!(method, Method::Drt);
            continue;
        }
        let mut out = IndirectLight::default();
        let e_conv = energy(&converged.radiance);
        let mut frames_to_1pct = None;
        for frame in 1..=200 {
            rt.apply(method, Bounces::Feedback, &ld, &mut out).unwrap();
            let diff: f64 = out
                .radiance
                .iter()
                .zip(&converged.radiance)
                .map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).abs() as f64).sum::<f64>())
                .sum();
            if frames_to_1pct.is_none() && diff <= 0.01 * e_conv {
                frames_to_1pct = Some(frame);
            }
        }
        let frames = frames_to_1pct.expect("feedback reaches 1% of Converged");
        assert!(frames < 60, "{method:?}: {frames} frames");
        for (a, b) in out.radiance.iter().zip(&converged.radiance) {
            for c in 0..3 {
                assert!(
                    (a[c] - b[c]).abs() <= 1e-4 * (1.0 + b[c].abs()),
                    "{a:?} {b:?}"
                );
            }
        }
        // A light that jumps every frame: feedback stays within the converged light of the
        // brightest frame (all light is non-negative, the operator monotone).
        rt.reset_feedback();
        let lights: Vec<DirectLight> = (0..8).map(|_| direct(&mut rng, n)).collect();
        let mut bound = 0.0f64;
        for l in &lights {
            rt.apply(method, tight, l, &mut converged).unwrap();
            bound = bound.max(energy(&converged.radiance));
        }
        let brightest = DirectLight {
            radiance: (0..n)
                .map(|t| {
                    std::array::from_fn(|c| {
                        lights.iter().map(|l| l.radiance[t][c]).fold(0.0, f32::max)
                    })
                })
                .collect(),
        };
        rt.apply(method, tight, &brightest, &mut converged).unwrap();
        let ceiling = energy(&converged.radiance);
        assert!(ceiling >= bound);
        for frame in 0..400 {
            rt.apply(method, Bounces::Feedback, &lights[frame % 8], &mut out)
                .unwrap();
            let e = energy(&out.radiance);
            assert!(
                e.is_finite() && e <= ceiling * (1.0 + 1e-4),
                "frame {frame}: {e}"
            );
        }
    }
}

#[cfg(feature = "rayon")]
#[test]
fn converged_is_bit_identical_at_one_and_two_threads() {
    let mut rng = Lcg(59);
    let b = drt_bundle(&mut rng, true, true, false);
    let ld = direct(&mut rng, b.layout.n_texels());
    let mut outputs = Vec::new();
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let mut rt = Runtime::new(b.clone());
        rt.set_parallel(threads > 1);
        let mut out = IndirectLight::default();
        pool.install(|| rt.apply(Method::Drt, Bounces::Fixed(6), &ld, &mut out))
            .unwrap();
        outputs.push(out);
        let mut out = IndirectLight::default();
        let converged = pool.install(|| rt.apply(Method::Drt, Bounces::default(), &ld, &mut out));
        outputs.push(IndirectLight {
            radiance: if converged.is_ok() {
                out.radiance
            } else {
                vec![]
            },
        });
    }
    assert_eq!(outputs[0], outputs[2]);
    assert_eq!(outputs[1], outputs[3]);
}
