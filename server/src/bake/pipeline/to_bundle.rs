//! The bake's results in the bundle's terms: layout, shapes, blocks, transport, the DRT
//! section, the probe volume, SH responses and the dense operator, each converted from the
//! engine's f64 operators (faer matrices) to the bundle's f32 types.
//!
//! Invariant: conversions only; what a section holds is decided by the stages
//! ([`super::stages`]), so the bundle stays a pure function of the scene.

use lightfarm_proto::bundle::{self, Bundle, Layout, SparseRows, SurfaceInfo, TransportOps};
use lightfarm_proto::scene::{Opening, Scene, Settings};
use rayon::prelude::*;

use crate::bake::cache::factors::FactorCache;
use crate::bake::drt::build::{DeltaBlock, DrtOperators};
use crate::bake::drt::compaction::{
    compact_entry as compact_delta_entry, compact_entry_keeping, compact_gather,
    DeltaCompactionStats,
};
use crate::bake::math::low_rank::LowRankError;
use crate::bake::math::matrix::to_matrix;
use crate::bake::mrt::shape::ShapeOperators;
use crate::bake::scene::geometry::{Geometry, Primitive, SurfaceOwner};
use crate::bake::sh::probe_volume::ProbeVolumeOps;
use crate::bake::sh::responses::ShResponseOps;
use crate::bake::transport::build::MrtTransport;
use crate::bake::transport::compaction::CompactTransport;

use super::plan::ShapePlan;
use super::stages::HeldTransport;
use super::BakeError;

/// One target block's compaction as the bundle ships it: f32 `y` and `z` (what the stage
/// hands on and the transport cache stores, so a cache hit reads half the bytes of the f64).
pub fn compact_entry(c: &CompactTransport) -> bundle::CompactEntry {
    bundle::CompactEntry {
        target_block: c.target_block as u32,
        sources: c.sources.iter().map(|s| *s as u32).collect(),
        y: to_matrix(&c.y),
        z: to_matrix(&c.z),
    }
}

/// The bundle's transport section: the compact form when the scene ships it (kind 3 when some
/// source has a shared basis, else kind 2, which older readers read too), else the transport
/// as traced or as lightfields.
pub fn transport_ops(compact: Option<bundle::SourceBases>, held: &HeldTransport) -> TransportOps {
    if let Some(compact) = compact {
        if compact.bases.is_empty() {
            TransportOps::Compact(compact.entries)
        } else {
            TransportOps::Factored(compact)
        }
    } else {
        let HeldTransport::Computed(mrt) = held else {
            unreachable!("a transport without compaction is held whole (stages::block_transport)")
        };
        match mrt {
            MrtTransport::Lightfield(blocks) => TransportOps::Lightfield(
                blocks
                    .iter()
                    .map(|b| bundle::PropEntry {
                        target_block: b.target_block as u32,
                        target_face: b.target_face.index() as u8,
                        source_block: b.source_block as u32,
                        matrix: to_matrix(&b.matrix),
                    })
                    .collect(),
            ),
            MrtTransport::Traced(blocks) => TransportOps::Traced(
                blocks
                    .iter()
                    .map(|b| bundle::TracedEntry {
                        target_block: b.target_block as u32,
                        source_block: b.source_block as u32,
                        matrix: to_matrix(&b.matrix),
                    })
                    .collect(),
            ),
        }
    }
}

/// The MRT bundle: layout, atlases, the unique shapes' operators, the blocks, the rooms and
/// `transport`; every later section empty. Opening operators ship only with lightfield
/// transport (the only kind the runtime applies them for).
pub fn mrt_bundle(
    scene: &Scene,
    openings: &[[Option<Opening>; 6]],
    plan: &ShapePlan,
    shapes: &[std::sync::Arc<ShapeOperators>],
    full_geometry: &Geometry,
    transport: TransportOps,
) -> Bundle {
    let ship_openings = matches!(transport, TransportOps::Lightfield(_));
    let layout = layout_of(scene, full_geometry);
    let surface_atlases = surface_atlases_of(full_geometry, &layout);
    let rooms = Some(rooms_of(scene, openings, full_geometry, &layout));
    Bundle {
        rooms,
        surface_atlases,
        layout,
        shapes: shapes
            .iter()
            .map(|s| bundle::ShapeOps {
                key: s.key.clone(),
                u_b: to_matrix(&s.u_b),
                t_db: to_matrix(&s.t_db),
                openings: s
                    .openings
                    .iter()
                    .filter(|_| ship_openings)
                    .map(|o| bundle::OpeningOps {
                        face: o.face.index() as u8,
                        u_r: to_matrix(&o.u_r),
                    })
                    .collect(),
            })
            .collect(),
        blocks: scene
            .blocks
            .iter()
            .enumerate()
            .map(|(b, block)| bundle::BlockOps {
                symmetry: (!plan.symmetry[b].is_identity()).then(|| bundle::BlockSymmetry {
                    symmetry: plan.symmetry[b],
                    closed: bundle::BlockSymmetry::mask(&block.closed_faces()),
                }),
                id: block.id.clone(),
                shape: plan.shape_index[b] as u32,
                texel_offset: full_geometry.block_texels[b].start as u32,
            })
            .collect(),
        transport: Some(transport),
        full: None,
        drt: None,
        probes: None,
        dnrt: None,
        sh: None,
        dynamic_shapes: Vec::new(),
    }
}

/// The bundle's DRT section from the DRT operators: delta entries and the exact gather in
/// low-rank form when `compact_deltas` (see [`crate::bake::drt::compaction`]), their
/// factorisations read from and stored in `factors` when given. Takes `ops`' delta entries
/// (nothing after the section reads them) and frees them as their compactions are made.
pub fn drt_section(
    bundle: &Bundle,
    ops: &mut DrtOperators,
    settings: &Settings,
    factors: Option<&FactorCache>,
) -> Result<(bundle::DrtOps, Option<DeltaCompactionStats>), BakeError> {
    let clutter: Vec<bundle::ClutterOps> = ops
        .clutter
        .iter()
        .map(|c| bundle::ClutterOps {
            id: c.id.clone(),
            texel_offset: c.texel_offset as u32,
            t_dc: to_matrix(&c.basis.basis.transpose().to_owned()),
        })
        .collect();
    if !settings.compact_deltas {
        let drt = bundle::DrtOps {
            clutter,
            entries: std::mem::take(&mut ops.entries)
                .iter()
                .map(to_entry)
                .collect(),
            buried: ops.buried.clone(),
            // In the form the bundle stores it (rows by column), so it decodes as it is here.
            direct_gather: ops.direct_gather.as_ref().map(|g| g.sorted()),
            replaced: ops.replaced.clone(),
        };
        return Ok((drt, None));
    }
    let low_rank = |e: LowRankError| BakeError::Drt(format!("delta compaction: {e}"));
    let mut stats = DeltaCompactionStats::default();
    let mut buried = ops.buried.clone();
    buried.sort_unstable();
    // The f64 entries are consumed a group at a time (every entry of a group on a worker of
    // its own), each group's pages handed back before the next: the bake never holds all of
    // them beside all of their compactions. Entries and statistics are taken in the entries'
    // order, as from one parallel pass.
    let mut entries = Vec::with_capacity(ops.entries.len());
    let mut pending = std::mem::take(&mut ops.entries).into_iter().peekable();
    while pending.peek().is_some() {
        let group: Vec<DeltaBlock> = pending.by_ref().take(DELTA_GROUP).collect();
        let (out, s) = compact_each(&group, |e, stats| {
            compact_entry_keeping(
                &e.rows,
                e.source,
                &e.matrix,
                &buried,
                settings.tolerance,
                factors,
                stats,
            )
        })
        .map_err(low_rank)?;
        drop(group);
        crate::bake::memory::release_freed();
        entries.extend(out);
        stats.merge(s);
    }
    let mut direct_gather = None;
    if let Some(g) = &ops.direct_gather {
        // Source ranges: every block's texels and every clutter object's.
        let ranges: Vec<(u32, u32)> = bundle
            .blocks
            .iter()
            .map(|b| (b.texel_offset, bundle.shapes[b.shape as usize].u_b.rows))
            .chain(clutter.iter().map(|c| (c.texel_offset, c.t_dc.cols)))
            .collect();
        let (gathered, rest) = compact_gather(g, &ranges, settings.tolerance, factors, &mut stats)
            .map_err(low_rank)?;
        entries.extend(gathered);
        direct_gather = rest.map(|g| g.sorted());
    }
    let drt = bundle::DrtOps {
        clutter,
        entries,
        buried: ops.buried.clone(),
        direct_gather,
        replaced: ops.replaced.clone(),
    };
    Ok((drt, Some(stats)))
}

/// Every entry of `entries` compacted by `compact` side by side (one worker per entry, each
/// SVD sequential), the results and statistics taken in the entries' order: the same as one
/// sequential pass.
fn compact_each<F>(
    entries: &[DeltaBlock],
    compact: F,
) -> Result<(Vec<bundle::DeltaEntry>, DeltaCompactionStats), LowRankError>
where
    F: Fn(&DeltaBlock, &mut DeltaCompactionStats) -> Result<Vec<bundle::DeltaEntry>, LowRankError>
        + Sync,
{
    let compacted: Vec<(Vec<bundle::DeltaEntry>, DeltaCompactionStats)> = entries
        .par_iter()
        .map(|e| {
            let mut stats = DeltaCompactionStats::default();
            let out = compact(e, &mut stats)?;
            Ok((out, stats))
        })
        .collect::<Result<_, LowRankError>>()?;
    let mut stats = DeltaCompactionStats::default();
    let mut out = Vec::with_capacity(compacted.len());
    for (entries, s) in compacted {
        out.extend(entries);
        stats.merge(s);
    }
    Ok((out, stats))
}

/// Delta entries compacted together by [`drt_section`] before their f64 matrices are freed:
/// enough to keep both cores busy through entries of very different sizes.
const DELTA_GROUP: usize = 64;

fn to_entry(e: &DeltaBlock) -> bundle::DeltaEntry {
    bundle::DeltaEntry {
        rows: e.rows.clone(),
        source: e.source,
        matrix: to_matrix(&e.matrix),
        mix: None,
    }
}

/// The bundle's probe volume (`U_dyn`), its entries in low-rank form where that is smaller when
/// `compact_deltas` ([`compact_entry`](crate::bake::drt::compaction::compact_entry) at the
/// scene's tolerance, as DRT's delta entries: both multiply block and clutter coefficients, and
/// nearby probes' rows are alike), with what that saved.
pub fn probe_section(
    volume: ProbeVolumeOps,
    settings: &Settings,
) -> Result<(bundle::ProbeVolume, Option<DeltaCompactionStats>), BakeError> {
    let (entries, stats) = if settings.compact_deltas {
        let (entries, stats) = compact_each(&volume.entries, |e, stats| {
            let entry = compact_delta_entry(
                e.rows.clone(),
                e.source,
                &e.matrix,
                settings.tolerance,
                None,
                stats,
            )?;
            Ok(vec![entry])
        })
        .map_err(|e| BakeError::Drt(format!("probe compaction: {e}")))?;
        (entries, Some(stats))
    } else {
        (volume.entries.iter().map(to_entry).collect(), None)
    };
    let section = bundle::ProbeVolume {
        origin: volume.origin.map(|x| x as f32),
        spacing: volume.spacing as f32,
        dims: volume.dims.map(|d| d as u32),
        slot: volume.slot,
        n_probes: volume.n_probes as u32,
        entries,
    };
    Ok((section, stats))
}

/// The bundle's SH responses.
pub fn sh_section(ops: &ShResponseOps) -> bundle::ShResponses {
    bundle::ShResponses {
        entries: ops
            .entries
            .iter()
            .map(|e| bundle::ShEntry {
                texels: e.texels.clone(),
                source: e.source,
                y: to_matrix(&e.y),
                z: to_matrix(&e.z),
            })
            .collect(),
    }
}

/// The dense operator's rows (per texel, `(column, value)` ascending) as the bundle's sparse
/// rows.
pub fn sparse_rows(rows: Vec<Vec<(u32, f32)>>) -> SparseRows {
    let mut sparse = SparseRows {
        n: rows.len() as u32,
        row_start: vec![0],
        cols: Vec::new(),
        values: Vec::new(),
    };
    for row in rows {
        for (c, v) in row {
            sparse.cols.push(c);
            sparse.values.push(v);
        }
        sparse.row_start.push(sparse.cols.len() as u32);
    }
    sparse
}

/// The bundle layout of a full geometry.
pub fn layout_of(scene: &Scene, g: &Geometry) -> Layout {
    let mut surfaces: Vec<SurfaceInfo> = Vec::new();
    for s in &g.surfaces {
        let n = s.n_texels as u32;
        let block_face = matches!(s.owner, SurfaceOwner::Block { .. });
        match surfaces.last_mut() {
            // Clutter boxes: six faces, one surface name. Block faces stay one surface each,
            // also where pieces of a long block (`bake::scene::pieces`) share a face's name:
            // each piece's face lies in its own room.
            Some(last) if last.name == s.name && !block_face => last.texel_count += n,
            _ => surfaces.push(SurfaceInfo {
                name: s.name.clone(),
                texel_offset: s.texel_offset as u32,
                texel_count: n,
            }),
        }
    }
    let f3 = |v: [f64; 3]| v.map(|x| x as f32);
    let mut rects = Vec::new();
    let mut triangles = Vec::new();
    for p in &g.primitives {
        match p {
            Primitive::Rect {
                axis,
                coord,
                min,
                max,
                ..
            } => rects.push(bundle::Rect {
                axis: *axis as u8,
                coord: *coord as f32,
                min: min.map(|x| x as f32),
                max: max.map(|x| x as f32),
            }),
            Primitive::Triangle { v, .. } => triangles.push(v.map(f3)),
        }
    }
    Layout {
        scene_name: scene.name.clone(),
        surfaces,
        positions: g.texels.iter().map(|t| f3(t.position)).collect(),
        normals: g.texels.iter().map(|t| f3(t.normal)).collect(),
        albedo: g.texels.iter().map(|t| f3(t.albedo)).collect(),
        texel_size: g
            .texels
            .iter()
            .map(|t| {
                let s = &g.surfaces[t.surface as usize];
                match s.owner {
                    // A mesh texel: the side of the square in the normal's dominant tangent
                    // plane whose lift onto the texel's plane has the texel's area
                    // (`docs/bundle-format.md`, layout).
                    SurfaceOwner::ClutterMesh { atlas, .. } => {
                        let area = g.mesh_atlases[atlas].0.texels[t.index as usize].area;
                        let dominant = t.normal.iter().fold(0.0f64, |m, x| m.max(x.abs()));
                        let side = (area * dominant).sqrt() as f32;
                        [side, side]
                    }
                    _ => [
                        ((s.max[0] - s.min[0]) / s.t as f64) as f32,
                        ((s.max[1] - s.min[1]) / s.t as f64) as f32,
                    ],
                }
            })
            .collect(),
        rects,
        triangles,
    }
}

/// The level's rooms ([`bundle::Rooms`]): every block's box and where its faces lead (from
/// `openings`, `Scene::openings`), and where each layout surface lies: a block face in its
/// block; a clutter object in every block its bounds touch (touching counts, so the list is a
/// superset), outside as well unless one block holds its bounds. Objects × blocks box tests.
pub fn rooms_of(
    scene: &Scene,
    openings: &[[Option<Opening>; 6]],
    g: &Geometry,
    layout: &Layout,
) -> bundle::Rooms {
    let rooms = scene
        .blocks
        .iter()
        .zip(openings)
        .map(|(block, open)| bundle::Room {
            min: block.min,
            max: block.max,
            faces: open.map(|o| match o {
                None => bundle::FaceLink::Closed,
                Some(Opening::Void) => bundle::FaceLink::Void,
                Some(Opening::Neighbour { block, .. }) => bundle::FaceLink::Neighbour(block as u32),
            }),
        })
        .collect();
    let place_of = |bounds: &[[f64; 3]; 2]| {
        let [lo, hi] = *bounds;
        let mut rooms = Vec::new();
        let mut inside_one = false;
        for (k, b) in scene.blocks.iter().enumerate() {
            if (0..3).all(|a| lo[a] <= b.max[a] && hi[a] >= b.min[a]) {
                rooms.push(k as u32);
                inside_one |= (0..3).all(|a| lo[a] >= b.min[a] && hi[a] <= b.max[a]);
            }
        }
        bundle::SurfacePlace::Object {
            rooms,
            outside: !inside_one,
        }
    };
    // The first engine surface of each layout surface, in one pass (layout surfaces are the
    // engine's in order, a clutter box's six faces merged into one).
    let mut firsts = Vec::with_capacity(layout.surfaces.len());
    for s in &g.surfaces {
        if let Some(info) = layout.surfaces.get(firsts.len()) {
            if info.texel_offset == s.texel_offset as u32 && info.name == s.name {
                firsts.push(s);
            }
        }
    }
    assert_eq!(
        firsts.len(),
        layout.surfaces.len(),
        "every layout surface comes from an engine surface"
    );
    let surfaces = firsts
        .into_iter()
        .map(|s| match s.owner {
            SurfaceOwner::Block { block, face } => bundle::SurfacePlace::Face {
                room: block as u32,
                face: face.index() as u8,
            },
            SurfaceOwner::ClutterBox { clutter, .. }
            | SurfaceOwner::ClutterMesh { clutter, .. } => {
                place_of(&g.clutter_shapes[clutter].bounds)
            }
        })
        .collect();
    bundle::Rooms { rooms, surfaces }
}

/// Each mesh surface's lightmap image (its atlas) for the bundle's layout.
pub fn surface_atlases_of(g: &Geometry, layout: &Layout) -> Vec<bundle::SurfaceAtlas> {
    g.mesh_atlases
        .iter()
        .map(|(atlas, surface)| {
            let name = &g.surfaces[*surface as usize].name;
            let index = layout
                .surfaces
                .iter()
                .position(|s| &s.name == name)
                .expect("every mesh surface is in the layout");
            bundle::SurfaceAtlas {
                surface: index as u32,
                width: atlas.width,
                height: atlas.height,
                texel_xy: atlas.texels.iter().map(|t| [t.x, t.y]).collect(),
            }
        })
        .collect()
}
