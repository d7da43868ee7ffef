//! Test fixtures (feature `testing`, for this crate's and the client's tests only): a seeded
//! generator and hand-built bundles that exercise every section kind — two blocks with traced
//! or lightfield transport, DRT with all four kinds of delta entry, a probe volume — so the
//! decoder fuzzing here (`tests/decode_fuzz.rs`) and the client runtime's tests mutate and
//! apply the same bytes.
//!
//! Also the smallest bundle ([`one_block_bundle`]: one block, MRT only) that the C ABI, fetch
//! and no-allocation tests build theirs on, the fuzz driver both fuzzers run
//! ([`fuzz_mutations`]), an allocation counter for the no-allocation tests
//! ([`CountingAlloc`]; each test binary installs it) and a box's triangles for the shadow
//! tests of posed objects ([`hexahedron`]).
//!
//! Invariant: deterministic; the same seed gives the same bundle bytes and the same mutations
//! on every platform.

#![allow(clippy::needless_range_loop)]

use crate::bundle::{section, BUNDLE_MAJOR, BUNDLE_MINOR};
use crate::bundle::{
    BlockOps, Bundle, ClutterOps, CompactEntry, DeltaEntry, DeltaSource, DrtOps, DynamicShape,
    GatherTiles, Layout, Matrix, OpeningOps, ProbeVolume, PropEntry, ShapeOps, SourceBases,
    SourceBasis, SparseRows, SurfaceInfo, TexelGather, TracedEntry, TransportOps,
};
use crate::container::write_container;

/// A fixed-seed linear congruential generator (the client tests' `Lcg`, same sequence).
pub struct Lcg(pub u64);

impl Lcg {
    /// The next 31 random bits (below 2³¹).
    pub fn next_u32(&mut self) -> u32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 33) as u32
    }
    /// Uniform in `[0, 1)`: 24 of the 31 bits [`Lcg::next_u32`] gives.
    pub fn unit(&mut self) -> f32 {
        (self.next_u32() >> 7) as f32 / (1u32 << 24) as f32
    }
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit()
    }
    /// A point with each coordinate uniform in `[lo, hi)`.
    pub fn point(&mut self, lo: f32, hi: f32) -> [f32; 3] {
        [self.range(lo, hi), self.range(lo, hi), self.range(lo, hi)]
    }
}

/// A box's six faces as corner quads, counter-clockwise seen from outside, corner `i` on the
/// +x side when bit 0 is set, +y bit 1, +z bit 2 (each quad makes triangles `q0 q1 q2` and
/// `q0 q2 q3`).
pub const BOX_QUADS: [[usize; 4]; 6] = [
    [0, 4, 6, 2],
    [1, 3, 7, 5],
    [0, 1, 5, 4],
    [2, 6, 7, 3],
    [0, 2, 3, 1],
    [4, 5, 7, 6],
];

/// The 12 triangles of a hexahedron whose corner `i` (numbered as in [`BOX_QUADS`]) is
/// `corner(i)`, outward-wound when it is a box: a box, or a slanted one (posed dynamic
/// objects in shadow tests).
pub fn hexahedron(corner: impl Fn(usize) -> [f32; 3]) -> Vec<[[f32; 3]; 3]> {
    BOX_QUADS
        .iter()
        .flat_map(|q| {
            let c = q.map(&corner);
            [[c[0], c[1], c[2]], [c[0], c[2], c[3]]]
        })
        .collect()
}

/// A Wavefront OBJ of the box `[lo, hi]`: its eight corners, then [`BOX_QUADS`] as two
/// outward-wound triangles each (mesh clutter and dynamic objects in end-to-end tests).
pub fn box_obj(lo: [f64; 3], hi: [f64; 3]) -> String {
    let mut s = String::new();
    for i in 0..8 {
        let [x, y, z] = [0, 1, 2].map(|k| if i >> k & 1 == 0 { lo[k] } else { hi[k] });
        s += &format!("v {x} {y} {z}\n");
    }
    for q in BOX_QUADS.map(|q| q.map(|c| c + 1)) {
        s += &format!(
            "f {} {} {}\nf {} {} {}\n",
            q[0], q[1], q[2], q[0], q[2], q[3]
        );
    }
    s
}

/// A random `rows × cols` matrix, entries in `[-1, 0)`: operators made of these, with
/// [`layout`]'s albedos below 0.5, have bounces that converge (what the runtime's tests of
/// all bounces need).
pub fn matrix(rng: &mut Lcg, rows: usize, cols: usize) -> Matrix {
    Matrix {
        rows: rows as u32,
        cols: cols as u32,
        data: (0..rows * cols).map(|_| rng.range(-1.0, 0.0)).collect(),
    }
}

/// A random sparse n × n dense-bounce operator (about a third of the entries set).
pub fn random_full(rng: &mut Lcg, n: usize) -> SparseRows {
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

pub fn layout(rng: &mut Lcg, surfaces: &[(&str, usize)]) -> Layout {
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
        // Below 0.5, so the random operators' bounces converge.
        albedo: (0..n)
            .map(|_| {
                [
                    rng.range(0.1, 0.5),
                    rng.range(0.1, 0.5),
                    rng.range(0.1, 0.5),
                ]
            })
            .collect(),
        rects: vec![],
        triangles: vec![],
    }
}

/// A shape of `texels` texels and rank `r` with random `U_b`, `T_d→b` and, per `(face, q)` in
/// `openings`, `U_r` (drawn in that order).
pub fn shape(
    rng: &mut Lcg,
    key: &str,
    texels: usize,
    r: usize,
    openings: &[(u8, usize)],
) -> ShapeOps {
    ShapeOps {
        key: key.into(),
        u_b: matrix(rng, texels, r),
        t_db: matrix(rng, r, texels),
        openings: openings
            .iter()
            .map(|&(face, q)| OpeningOps {
                face,
                u_r: matrix(rng, texels, q),
            })
            .collect(),
    }
}

/// Lightfield transport with a random matrix (q × r of the source) per `(target block, target
/// face, q, source block)` entry, drawn in order; `r[b]` is block b's rank.
pub fn lightfield_transport(
    rng: &mut Lcg,
    entries: &[(u32, u8, usize, u32)],
    r: &[usize],
) -> TransportOps {
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
}

/// Traced transport with a random matrix (target texels × source rank) per `(target block,
/// source block)` pair, drawn in order; `texels[b]` and `r[b]` are block b's texels and rank.
pub fn traced_transport(
    rng: &mut Lcg,
    pairs: &[(u32, u32)],
    texels: &[usize],
    r: &[usize],
) -> TransportOps {
    TransportOps::Traced(
        pairs
            .iter()
            .map(|&(t, s)| TracedEntry {
                target_block: t,
                source_block: s,
                matrix: matrix(rng, texels[t as usize], r[s as usize]),
            })
            .collect(),
    )
}

/// Blocks `(id, shape, first texel)` without symmetries.
pub fn blocks(list: &[(&str, u32, u32)]) -> Vec<BlockOps> {
    list.iter()
        .map(|&(id, shape, texel_offset)| BlockOps {
            symmetry: None,
            id: id.into(),
            shape,
            texel_offset,
        })
        .collect()
}

/// Two blocks (a: shape 0, 4 texels, r = 2, opening +x (q = 3); b: shape 1, 6 texels,
/// r = 3, opening -x (q = 2)) with traced or lightfield transport between them, one clutter
/// object (box: 4 texels, m = 2) or two (plus lamp: 3 texels, m = 3), and delta entries of
/// all four kinds: block rows from a block, block rows from clutter, clutter rows from a
/// block, clutter rows from clutter (plus a self-entry, an empty one and overlapping rows).
pub fn drt_bundle(rng: &mut Lcg, lightfield: bool, two_clutter: bool, full: bool) -> Bundle {
    let mut surfaces = vec![("block:a/+x", 4), ("block:b/-x", 6), ("clutter:box", 4)];
    if two_clutter {
        surfaces.push(("clutter:lamp", 3));
    }
    let layout = layout(rng, &surfaces);
    let n = layout.n_texels();
    let shapes = vec![
        shape(rng, "s0", 4, 2, &[(1, 3)]),
        shape(rng, "s1", 6, 3, &[(0, 2)]),
    ];
    let blocks = blocks(&[("a", 0, 0), ("b", 1, 4)]);
    let r = [2usize, 3];
    let transport = if lightfield {
        lightfield_transport(rng, &[(0, 1, 3, 1), (1, 0, 2, 0), (1, 0, 2, 1)], &r)
    } else {
        traced_transport(rng, &[(0, 1), (1, 0), (1, 1)], &[4, 6], &r)
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
        ..Bundle::default()
    }
}

/// An exact gather of `b`'s clutter texels (a [`drt_bundle`]: every texel of surfaces named
/// `clutter:…`) from its block texels, as a bake of 1,024 rays per texel makes it: each row
/// reads a random half of the block texels, with hit counts from 1 to `max_count` (over 255,
/// the DRT section is written as kind 20's escaped counts); each row's first count is
/// `max_count`, the first row's second 1 (so the weights' unit is one ray).
pub fn with_gather(rng: &mut Lcg, b: &mut Bundle, max_count: u32) {
    let unit = 1.0 / 1024.0;
    let mut rows = Vec::new();
    let mut blocks = Vec::new();
    for s in &b.layout.surfaces {
        let texels = s.texel_offset..s.texel_offset + s.texel_count;
        if s.name.starts_with("clutter:") {
            rows.extend(texels);
        } else {
            blocks.extend(texels);
        }
    }
    let mut g = TexelGather {
        row_start: vec![0],
        ..TexelGather::default()
    };
    for row in rows {
        g.rows.push(row);
        for &c in &blocks {
            let in_row = g.cols.len() - *g.row_start.last().unwrap() as usize;
            let one = g.rows.len() == 1 && in_row == 1;
            if in_row == 0 || one || rng.next_u32().is_multiple_of(2) {
                let count = match (in_row, one) {
                    (0, _) => max_count,
                    (_, true) => 1,
                    _ => 1 + rng.next_u32() % max_count,
                };
                g.cols.push(c);
                g.values.push(unit * count as f32);
            }
        }
        g.row_start.push(g.cols.len() as u32);
    }
    b.drt.as_mut().expect("a DRT bundle").direct_gather = Some(g);
}

/// Pools `b`'s exact gather by tile as a bake does (format 2.6, [`GatherTiles`]): the tiles
/// are runs of up to three consecutive texels of each block surface, and in every row the
/// entries of at most `max_hits` rays (weights of [`with_gather`]'s unit, 1/1,024) on a tiled
/// texel move to their tile's column, their counts summed, after the row's other entries.
pub fn with_tiles(b: &mut Bundle, max_hits: u32) {
    let n = b.layout.n_texels() as u32;
    let mut tile_of = vec![u32::MAX; n as usize];
    let mut tiles = GatherTiles::default();
    for s in b
        .layout
        .surfaces
        .iter()
        .filter(|s| !s.name.starts_with("clutter:"))
    {
        let texels: Vec<u32> = (s.texel_offset..s.texel_offset + s.texel_count).collect();
        for run in texels.chunks(3) {
            for &t in run {
                tile_of[t as usize] = tiles.len() as u32;
            }
            tiles.push(run);
        }
    }
    let unit = 1.0 / 1024.0;
    let g = b
        .drt
        .as_mut()
        .and_then(|d| d.direct_gather.as_mut())
        .expect("a bundle with a gather");
    let mut out = TexelGather {
        rows: g.rows.clone(),
        row_start: vec![0],
        ..TexelGather::default()
    };
    for i in 0..g.rows.len() {
        let mut pooled = std::collections::BTreeMap::<u32, u32>::new();
        for k in g.row_start[i] as usize..g.row_start[i + 1] as usize {
            let (c, v) = (g.cols[k], g.values[k]);
            let hits = (v / unit).round() as u32;
            match tile_of[c as usize] {
                tile if tile != u32::MAX && hits <= max_hits => {
                    *pooled.entry(tile).or_default() += hits
                }
                _ => {
                    out.cols.push(c);
                    out.values.push(v);
                }
            }
        }
        for (tile, hits) in pooled {
            out.cols.push(n + tile);
            out.values.push(unit * hits as f32);
        }
        out.row_start.push(out.cols.len() as u32);
    }
    out.tiles = tiles;
    *g = out;
}

/// A [`drt_bundle`] in which every texel index list of the DRT section is non-empty: an exact
/// gather with counts over 255 ([`with_gather`]), pooled by tile ([`with_tiles`]), and three
/// replaced texels. What the kind-22 and kind-23 fuzz tests mutate (formats 2.7 and 2.8, every
/// list packed; in 2.8 the gather modelled).
pub fn drt_bundle_with_every_list(rng: &mut Lcg) -> Bundle {
    let mut b = drt_bundle(rng, false, true, true);
    with_gather(rng, &mut b, 700);
    with_tiles(&mut b, 2);
    b.drt.as_mut().expect("a DRT bundle").replaced = vec![0, 5, 9];
    b
}

/// [`drt_bundle`]'s blocks (a: 4 texels, r = 2; b: 6 texels, r = 3) with compact transport
/// through shared source bases (transport kind 3, section 16): block b's light through a 2 × 3
/// basis, block a's as it is; a receives from b (k = 2), b from a and itself (k = 3).
pub fn factored_bundle(rng: &mut Lcg) -> Bundle {
    let mut b = drt_bundle(rng, false, true, true);
    let entry = |rng: &mut Lcg, target: u32, sources: Vec<u32>, texels: usize, k: usize| {
        let width = sources.iter().map(|&s| [2usize, 2][s as usize]).sum();
        CompactEntry {
            target_block: target,
            sources,
            y: matrix(rng, texels, k),
            z: matrix(rng, k, width),
        }
    };
    b.transport = Some(TransportOps::Factored(SourceBases {
        bases: vec![SourceBasis {
            source_block: 1,
            q: matrix(rng, 2, 3),
        }],
        entries: vec![
            entry(rng, 0, vec![1], 4, 2),
            entry(rng, 1, vec![0, 1], 6, 3),
        ],
    }));
    b
}

/// Probes of the probe test bundle; probe 5 (rows 45..54) is fed by no entry.
pub const N_PROBES: usize = 7;

/// [`drt_bundle`] (blocks a, b; clutter box) with a 2×2×2 probe volume whose grid point
/// (1, 1, 0) is empty (7 probes), and probe entries from both blocks and (with `drt`) the
/// clutter object, overlapping rows, an empty entry and the last row. Without `drt` the
/// bundle has no DRT section and no clutter-sourced probe entries.
pub fn probe_bundle(rng: &mut Lcg, drt: bool) -> Bundle {
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

/// A closed cube of half-size `half` about the origin (12 triangles): a dynamic object's
/// shape.
pub fn cube(id: &str, half: f32) -> DynamicShape {
    DynamicShape {
        object: id.into(),
        albedo: [0.5; 3],
        triangles: hexahedron(|i| [0, 1, 2].map(|b| if i >> b & 1 == 0 { -half } else { half })),
    }
}

/// [`probe_bundle`] without DRT (texels on the x axis at x = 0, 1, …, 13 facing +z, a probe
/// volume) with a dynamic object `ball` (a [`cube`] of half-size 0.3 m) and its DNRT grid:
/// 5³ points of positive reflection and smaller occlusion terms varying with the point, inner
/// and outer half-extents 0.6 and 1.5 m; albedo a fifth of `probe_bundle`'s.
pub fn ball_bundle() -> Bundle {
    use crate::dnrt_grid::{DnrtCodec, DnrtGrid, DnrtNormals, DnrtPlacement, SLOTS};
    let mut bundle = probe_bundle(&mut Lcg(11), false);
    let (n, n_sh) = (5usize, 9usize);
    let values: Vec<f64> = (0..n * n * n * SLOTS * n_sh)
        .map(|k| {
            let (slot, s) = (k / n_sh % SLOTS, k % n_sh);
            let v = 0.02 + 0.001 * (k % 37) as f64 / (1 + s) as f64;
            if slot == 3 {
                0.3 * v
            } else {
                v
            }
        })
        .collect();
    let grid = DnrtGrid::encode_values(
        "ball",
        [0.0; 3],
        0.3,
        0.6,
        1.5,
        n as u32,
        n_sh as u32,
        DnrtPlacement::Regular,
        DnrtNormals::Intermediate,
        DnrtCodec::F32,
        vec![[0.0, 0.0]; 2 * n_sh],
        &values,
    );
    bundle.dnrt = Some(vec![grid]);
    bundle.dynamic_shapes = vec![cube("ball", 0.3)];
    // Dark enough that all bounces of the random operators converge.
    for a in &mut bundle.layout.albedo {
        *a = a.map(|x| 0.2 * x);
    }
    bundle
}

/// `n` texels in a row on the floor face of block `strip` (1 m apart, albedo (0.5, 0.6, 0.7)):
/// the layout of the no-allocation tests' [`one_block_bundle`]s.
pub fn strip_layout(n: usize) -> Layout {
    Layout {
        scene_name: "strip".into(),
        surfaces: vec![SurfaceInfo {
            name: "block:strip/-y".into(),
            texel_offset: 0,
            texel_count: n as u32,
        }],
        positions: (0..n).map(|i| [i as f32, 0.0, 0.0]).collect(),
        normals: vec![[0.0, 1.0, 0.0]; n],
        albedo: vec![[0.5, 0.6, 0.7]; n],
        texel_size: vec![[1.0, 1.0]; n],
        rects: vec![],
        triangles: vec![],
    }
}

/// One block `room` of two 0.5 m floor texels at (0.25, 0, 0.25) and (0.75, 0, 0.25) (albedo
/// grey and blue-ish) whose only operator averages them: `U_b = [1, 1]ᵀ`, `T_d→b = [½, ½]`, so
/// MRT gives `ρ_t · (l_0 + l_1) / 2` at each texel (the C ABI's tests).
pub fn two_texel_bundle() -> Bundle {
    let layout = Layout {
        scene_name: "two texels".into(),
        surfaces: vec![SurfaceInfo {
            name: "block:room/-y".into(),
            texel_offset: 0,
            texel_count: 2,
        }],
        positions: vec![[0.25, 0.0, 0.25], [0.75, 0.0, 0.25]],
        normals: vec![[0.0, 1.0, 0.0]; 2],
        albedo: vec![[0.5, 0.5, 0.5], [0.25, 0.5, 1.0]],
        texel_size: vec![[0.5, 0.5]; 2],
        rects: vec![],
        triangles: vec![],
    };
    let u_b = Matrix::from_fn(2, 1, |_, _| 1.0);
    let t_db = Matrix::from_fn(1, 2, |_, _| 0.5);
    one_block_bundle(layout, "room", "pair", u_b, t_db)
}

/// A bundle of one block (id `block`, at texel 0) that holds every texel of `layout`, lit by
/// MRT alone: one shape `key` with `u_b` (texels × r) and `t_db` (r × texels), no openings,
/// and no other section.
pub fn one_block_bundle(
    layout: Layout,
    block: &str,
    key: &str,
    u_b: Matrix,
    t_db: Matrix,
) -> Bundle {
    Bundle {
        layout,
        shapes: vec![ShapeOps {
            key: key.into(),
            u_b,
            t_db,
            openings: vec![],
        }],
        blocks: vec![BlockOps {
            symmetry: None,
            id: block.into(),
            shape: 0,
            texel_offset: 0,
        }],
        ..Bundle::default()
    }
}

/// A container of raw (uncompressed) sections, with fresh lengths, checksums and table of
/// contents, so edits inside a payload reach the bundle's validation.
pub fn join_sections(sections: &[(u32, Vec<u8>)]) -> Vec<u8> {
    write_container(BUNDLE_MAJOR, BUNDLE_MINOR, sections, 0).0
}

/// What [`fuzz_mutations`] hands its check: which kind of edit made the bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mutation {
    /// The unmutated encoding (as written, then re-joined from its raw sections).
    Unmutated,
    /// One byte anywhere in the file (the checksums catch nearly all of these).
    FileByte,
    /// The file cut short.
    TruncatedFile,
    /// One byte inside a section, length and checksum repaired, so validation sees it.
    SectionByte,
    /// A section cut short inside, length and checksum repaired.
    TruncatedSection,
}

/// Of the [`Mutation::SectionByte`] edits: how many were tried and how many `check` accepted.
#[derive(Clone, Copy, Debug, Default)]
pub struct FuzzCounts {
    pub tried: usize,
    pub accepted: usize,
}

/// Byte mutations and truncations of `b`'s encoding, half of those inside sections in the
/// section of kind `focus`: 1,500 file bytes, 500 file truncations, 3,000 section bytes and
/// 1,000 section truncations, each handed to `check` (which returns whether the bytes
/// decoded). A `focus` on kind 13, 20 or 21 mutates the bundle as a 2.6 writer wrote it
/// ([`Bundle::raw_sections_as_2_6`]), on kind 22 as a 2.7 writer did
/// ([`Bundle::raw_sections_as_2_7`]): kinds the current writer no longer writes. Panics if the
/// bundle has no `focus` section or `check` refuses the unmutated encoding.
pub fn fuzz_mutations(
    rng: &mut Lcg,
    b: &Bundle,
    focus: u32,
    mut check: impl FnMut(Mutation, &[u8]) -> bool,
) -> FuzzCounts {
    // A focus on a DRT kind only older writers wrote: the bundle as that writer wrote it.
    let older = match focus {
        section::DRT_REPLACING | section::DRT_WIDE_COUNTS | section::DRT_TILED_GATHER => {
            Some(b.raw_sections_as_2_6())
        }
        section::DRT_PACKED_LISTS => Some(b.raw_sections_as_2_7()),
        _ => None,
    };
    let (sections, bytes) = match older {
        Some(sections) => {
            let bytes = join_sections(&sections);
            (sections, bytes)
        }
        None => (b.raw_sections(), b.encode()),
    };
    assert!(check(Mutation::Unmutated, &bytes));
    assert!(check(Mutation::Unmutated, &join_sections(&sections)));
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
    // Half in the focus section, half in any.
    let pick = |k: usize, rng: &mut Lcg| {
        if k % 2 == 0 {
            focus_at
        } else {
            rng.next_u32() as usize % sections.len()
        }
    };
    let mut counts = FuzzCounts::default();
    for _ in 0..1500 {
        let mut m = bytes.clone();
        let at = rng.next_u32() as usize % m.len();
        mutate(&mut m[at], rng);
        check(Mutation::FileByte, &m);
    }
    for _ in 0..500 {
        let len = rng.next_u32() as usize % bytes.len();
        check(Mutation::TruncatedFile, &bytes[..len]);
    }
    for k in 0..3000 {
        let mut s = sections.clone();
        let i = pick(k, rng);
        let payload = &mut s[i].1;
        let at = rng.next_u32() as usize % payload.len();
        mutate(&mut payload[at], rng);
        counts.tried += 1;
        counts.accepted += check(Mutation::SectionByte, &join_sections(&s)) as usize;
    }
    for k in 0..1000 {
        let mut s = sections.clone();
        let i = pick(k, rng);
        let len = rng.next_u32() as usize % s[i].1.len();
        s[i].1.truncate(len);
        check(Mutation::TruncatedSection, &join_sections(&s));
    }
    counts
}

thread_local! {
    static ALLOCS: std::cell::Cell<u64> = const { std::cell::Cell::new(0) };
}

/// A global allocator that counts the current thread's allocations and reallocations (tests
/// run on separate threads, so a test sees only its own). A test binary installs it with
/// `#[global_allocator] static GLOBAL: CountingAlloc = CountingAlloc;` and reads
/// [`allocs`].
pub struct CountingAlloc;

unsafe impl std::alloc::GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        let _ = ALLOCS.try_with(|a| a.set(a.get() + 1));
        unsafe { std::alloc::System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        unsafe { std::alloc::System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCS.try_with(|a| a.set(a.get() + 1));
        unsafe { std::alloc::System.realloc(ptr, layout, new_size) }
    }
}

/// Allocations the current thread made through [`CountingAlloc`] so far.
pub fn allocs() -> u64 {
    ALLOCS.with(|a| a.get())
}
