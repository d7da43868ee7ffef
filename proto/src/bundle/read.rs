//! Reading a bundle: [`Bundle::decode`] and [`Bundle::decode_prefix`] turn the sections the
//! container hands over into a [`Bundle`] and validate it. Every section kind a 2.x writer
//! writes is read here, and DRT kinds 6 and 11 (older writers' choice; kind 13's layout without
//! the replaced list) as kind 13 with nothing replaced; what only 1.x bundles hold in another
//! layout is read by `legacy_1x`.
//!
//! Invariant: reading never panics and never allocates more than the bytes left can fill
//! (capacities are capped by the remaining input); a section must be consumed exactly (trailing
//! bytes are an error), and `Ok` means [`Bundle::validate`] passed.

use crate::container::read_sections;
use crate::wire::Reader;

use super::delta_entries::read_entries;
use super::index_lists::{read_index_list, IndexLists};
use super::sections::{is_known_section, section, section_name};
use super::{dynamic_shapes, gather_encoding, legacy_1x, sh_responses, symmetric_blocks};
use super::{
    Bundle, BundleError, ClutterOps, CompactEntry, DrtOps, GatherTiles, Layout, Matrix, OpeningOps,
    PartialBundle, ProbeVolume, PropEntry, Rect, Rooms, ShapeOps, SourceBases, SourceBasis,
    SparseRows, SurfaceAtlas, SurfaceInfo, TracedEntry, TransportOps, READABLE_MAJORS,
};

fn read_vec3s(r: &mut Reader, what: &str) -> Result<Vec<[f32; 3]>, BundleError> {
    let flat = r.f32s()?;
    if flat.len() % 3 != 0 {
        return Err(BundleError::Invalid(format!(
            "{what}: length {} is not a multiple of 3",
            flat.len()
        )));
    }
    if flat.iter().any(|x| !x.is_finite()) {
        return Err(BundleError::Invalid(format!("{what}: value not finite")));
    }
    Ok(flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

impl Layout {
    fn read(r: &mut Reader) -> Result<Layout, BundleError> {
        let scene_name = r.str()?;
        let n_surfaces = r.u32()? as usize;
        let mut surfaces = Vec::with_capacity(n_surfaces.min(r.remaining() / 12));
        for _ in 0..n_surfaces {
            surfaces.push(SurfaceInfo {
                name: r.str()?,
                texel_offset: r.u32()?,
                texel_count: r.u32()?,
            });
        }
        let positions = read_vec3s(r, "layout positions")?;
        let normals = read_vec3s(r, "layout normals")?;
        let albedo = read_vec3s(r, "layout albedo")?;
        let n = positions.len();
        let sizes = r.f32s()?;
        if normals.len() != n || albedo.len() != n || sizes.len() != 2 * n {
            return Err(BundleError::Invalid(
                "layout: positions, normals, albedo and texel sizes differ in length".into(),
            ));
        }
        if sizes.iter().any(|x| !x.is_finite() || *x < 0.0) {
            return Err(BundleError::Invalid(
                "layout: texel size not finite and non-negative".into(),
            ));
        }
        let texel_size = sizes.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        let mut next = 0u64;
        for s in &surfaces {
            if s.texel_offset as u64 != next {
                return Err(BundleError::Invalid(format!(
                    "layout: surface {} is not contiguous",
                    s.name
                )));
            }
            next += s.texel_count as u64;
        }
        if next != n as u64 {
            return Err(BundleError::Invalid(
                "layout: surfaces do not cover the texels".into(),
            ));
        }
        let n_rects = r.u32()? as usize;
        let mut rects = Vec::with_capacity(n_rects.min(r.remaining() / 21));
        for _ in 0..n_rects {
            let rect = Rect {
                axis: r.u8()?,
                coord: r.f32()?,
                min: [r.f32()?, r.f32()?],
                max: [r.f32()?, r.f32()?],
            };
            let finite =
                rect.coord.is_finite() && rect.min.iter().chain(&rect.max).all(|x| x.is_finite());
            if rect.axis > 2 || !finite {
                return Err(BundleError::Invalid(
                    "layout: bad occluder rectangle".into(),
                ));
            }
            rects.push(rect);
        }
        let flat = r.f32s()?;
        if flat.len() % 9 != 0 || flat.iter().any(|x| !x.is_finite()) {
            return Err(BundleError::Invalid("layout: bad triangle list".into()));
        }
        let triangles = flat
            .chunks_exact(9)
            .map(|c| [[c[0], c[1], c[2]], [c[3], c[4], c[5]], [c[6], c[7], c[8]]])
            .collect();
        Ok(Layout {
            scene_name,
            surfaces,
            positions,
            normals,
            albedo,
            texel_size,
            rects,
            triangles,
        })
    }
}

impl Bundle {
    /// Decodes and validates a whole bundle. Any byte string gives `Ok` or `Err`, never a
    /// panic; a bundle cut short (no table of contents) is an error.
    pub fn decode(bytes: &[u8]) -> Result<Bundle, BundleError> {
        let sections = read_sections(bytes, READABLE_MAJORS, is_known_section, false)?;
        Bundle::from_sections(sections.sections)
    }

    /// Decodes what has arrived of a bundle that is still streaming: every complete section
    /// before the cut, validated together. Needs the layout, shape and block sections (the
    /// first three); the MRT transport, DRT and probe sections are used when present.
    pub fn decode_prefix(bytes: &[u8]) -> Result<PartialBundle, BundleError> {
        let sections = read_sections(bytes, READABLE_MAJORS, is_known_section, true)?;
        let present = sections
            .sections
            .iter()
            .map(|(k, _)| section_name(*k))
            .collect();
        Ok(PartialBundle {
            bundle: Bundle::from_sections(sections.sections)?,
            complete: sections.complete,
            present,
        })
    }

    fn from_sections(sections: Vec<(u32, Vec<u8>)>) -> Result<Bundle, BundleError> {
        let (mut layout, mut shapes, mut blocks, mut transport, mut full, mut drt, mut probes) =
            (None, None, None, None, None, None, None);
        let (mut dnrt, mut sh) = (None, None);
        let mut surface_atlases = Vec::new();
        let mut rooms = None;
        let mut dynamic_shapes = Vec::new();
        for (kind, payload) in &sections {
            let mut p = Reader::new(payload);
            match *kind {
                section::LAYOUT => layout = Some(Layout::read(&mut p)?),
                section::SHAPES => shapes = Some(read_shapes(&mut p)?),
                section::BLOCKS => blocks = Some(legacy_1x::read_blocks(&mut p)?),
                section::BLOCKS_SYMMETRIC => blocks = Some(symmetric_blocks::read_blocks(&mut p)?),
                section::TRANSPORT | section::TRANSPORT_SOURCE_BASES => {
                    let t = read_transport(&mut p)?;
                    // Kind 3 lives in its own section, which older readers skip; the other
                    // kinds in section 4, which they read.
                    if (*kind == section::TRANSPORT_SOURCE_BASES)
                        != matches!(t, TransportOps::Factored(_))
                    {
                        return Err(BundleError::Invalid(format!(
                            "transport section kind {kind} holds the wrong transport kind"
                        )));
                    }
                    if transport.replace(t).is_some() {
                        return Err(BundleError::Invalid("two transport sections".into()));
                    }
                }
                section::FULL => full = Some(read_full(&mut p)?),
                section::DRT | section::DRT_LOW_RANK => {
                    drt = Some(read_drt(&mut p, false, IndexLists::Plain, false)?)
                }
                section::DRT_REPLACING
                | section::DRT_WIDE_COUNTS
                | section::DRT_TILED_GATHER
                | section::DRT_PACKED_LISTS
                | section::DRT_MODELLED_GATHER => {
                    let wide = *kind != section::DRT_REPLACING;
                    let modelled = *kind == section::DRT_MODELLED_GATHER;
                    let lists = if modelled || *kind == section::DRT_PACKED_LISTS {
                        IndexLists::Packed
                    } else {
                        IndexLists::Plain
                    };
                    let mut d = read_drt(&mut p, wide, lists, modelled)?;
                    d.replaced = read_index_list(&mut p, lists)?;
                    if *kind != section::DRT_REPLACING && *kind != section::DRT_WIDE_COUNTS {
                        let tiles = GatherTiles::read(&mut p, lists)?;
                        match d.direct_gather.as_mut() {
                            Some(g) => g.tiles = tiles,
                            None if tiles.is_empty() => {}
                            None => {
                                return Err(BundleError::Invalid(
                                    "drt: gather tiles without a gather".into(),
                                ))
                            }
                        }
                    }
                    drt = Some(d);
                }
                section::PROBES | section::PROBES_LOW_RANK => probes = Some(read_probes(&mut p)?),
                section::DNRT | section::DNRT_PLANAR => dnrt = Some(read_dnrt(&mut p)?),
                section::SH => sh = Some(sh_responses::read_sh(&mut p)?),
                section::LIGHTMAP => surface_atlases = read_surface_atlases(&mut p)?,
                section::ROOMS => rooms = Some(Rooms::read(&mut p)?),
                section::DYNAMIC_SHAPES => dynamic_shapes = dynamic_shapes::read(&mut p)?,
                _ => {} // read_sections passes known kinds only
            }
            if p.remaining() != 0 {
                return Err(BundleError::Invalid(format!(
                    "{} section has {} trailing bytes",
                    section_name(*kind),
                    p.remaining()
                )));
            }
        }
        let bundle = Bundle {
            layout: layout.ok_or(BundleError::Missing("layout"))?,
            shapes: shapes.ok_or(BundleError::Missing("shapes"))?,
            blocks: blocks.ok_or(BundleError::Missing("blocks"))?,
            transport,
            full,
            drt,
            probes,
            dnrt,
            sh,
            surface_atlases,
            rooms,
            dynamic_shapes,
        };
        bundle.validate()?;
        Ok(bundle)
    }
}

fn read_surface_atlases(r: &mut Reader) -> Result<Vec<SurfaceAtlas>, BundleError> {
    let n = r.u32()? as usize;
    let mut out = Vec::with_capacity(n.min(r.remaining() / 20));
    for _ in 0..n {
        let (surface, width, height) = (r.u32()?, r.u32()?, r.u32()?);
        let xy = r.u32s()?;
        if xy.len() % 2 != 0 {
            return Err(BundleError::Invalid(
                "lightmap: odd texel coordinate count".into(),
            ));
        }
        out.push(SurfaceAtlas {
            surface,
            width,
            height,
            texel_xy: xy.chunks_exact(2).map(|c| [c[0], c[1]]).collect(),
        });
    }
    Ok(out)
}

fn read_shapes(r: &mut Reader) -> Result<Vec<ShapeOps>, BundleError> {
    let n = r.u32()? as usize;
    let mut out = Vec::with_capacity(n.min(r.remaining() / 16));
    for k in 0..n {
        let key = r.str()?;
        let u_b = Matrix::read(r, &format!("shape {k} U_b"))?;
        let t_db = Matrix::read(r, &format!("shape {k} T_d→b"))?;
        let n_open = r.u32()? as usize;
        let mut openings = Vec::with_capacity(n_open.min(6));
        for _ in 0..n_open {
            let face = r.u8()?;
            openings.push(OpeningOps {
                face,
                u_r: Matrix::read(r, &format!("shape {k} U_r"))?,
            });
        }
        out.push(ShapeOps {
            key,
            u_b,
            t_db,
            openings,
        });
    }
    Ok(out)
}

fn read_transport(r: &mut Reader) -> Result<TransportOps, BundleError> {
    let kind = r.u8()?;
    let n = r.u32()? as usize;
    match kind {
        0 => {
            let mut out = Vec::with_capacity(n.min(r.remaining() / 17));
            for _ in 0..n {
                out.push(PropEntry {
                    target_block: r.u32()?,
                    target_face: r.u8()?,
                    source_block: r.u32()?,
                    matrix: Matrix::read(r, "transport")?,
                });
            }
            Ok(TransportOps::Lightfield(out))
        }
        1 => {
            let mut out = Vec::with_capacity(n.min(r.remaining() / 16));
            for _ in 0..n {
                out.push(TracedEntry {
                    target_block: r.u32()?,
                    source_block: r.u32()?,
                    matrix: Matrix::read(r, "transport")?,
                });
            }
            Ok(TransportOps::Traced(out))
        }
        2 => Ok(TransportOps::Compact(read_compact_entries(r, n)?)),
        3 => {
            let mut bases = Vec::with_capacity(n.min(r.remaining() / 14));
            for _ in 0..n {
                bases.push(SourceBasis {
                    source_block: r.u32()?,
                    q: Matrix::read(r, "transport source basis")?,
                });
            }
            let n = r.u32()? as usize;
            Ok(TransportOps::Factored(SourceBases {
                bases,
                entries: read_compact_entries(r, n)?,
            }))
        }
        k => Err(BundleError::Invalid(format!("transport: unknown kind {k}"))),
    }
}

/// `n` compact transport entries (kinds 2 and 3).
fn read_compact_entries(r: &mut Reader, n: usize) -> Result<Vec<CompactEntry>, BundleError> {
    let mut out = Vec::with_capacity(n.min(r.remaining() / 30));
    for _ in 0..n {
        out.push(CompactEntry {
            target_block: r.u32()?,
            sources: r.u32s()?,
            y: Matrix::read(r, "transport y")?,
            z: Matrix::read(r, "transport z")?,
        });
    }
    Ok(out)
}

fn read_full(r: &mut Reader) -> Result<SparseRows, BundleError> {
    Ok(SparseRows {
        n: r.u32()?,
        row_start: r.u32s()?,
        cols: r.u32s()?,
        values: r.f32s()?,
    })
}

/// A DRT section's common layout; `wide_counts` for sections 20–23 (escaped gather counts),
/// `lists` the form of its texel index lists (packed in sections 22 and 23), `modelled` for
/// section 23 (gather form 3).
fn read_drt(
    r: &mut Reader,
    wide_counts: bool,
    lists: IndexLists,
    modelled: bool,
) -> Result<DrtOps, BundleError> {
    let n_clutter = r.u32()? as usize;
    let mut clutter = Vec::with_capacity(n_clutter.min(r.remaining() / 16));
    for _ in 0..n_clutter {
        clutter.push(ClutterOps {
            id: r.str()?,
            texel_offset: r.u32()?,
            t_dc: Matrix::read(r, "drt clutter")?,
        });
    }
    let entries = read_entries(r, lists)?;
    let buried = read_index_list(r, lists)?;
    let direct_gather = gather_encoding::read_gather(r, wide_counts, lists, modelled)?;
    Ok(DrtOps {
        clutter,
        entries,
        buried,
        direct_gather,
        replaced: Vec::new(),
    })
}

fn read_probes(r: &mut Reader) -> Result<ProbeVolume, BundleError> {
    let origin = [r.f32()?, r.f32()?, r.f32()?];
    let spacing = r.f32()?;
    let dims = [r.u32()?, r.u32()?, r.u32()?];
    let slot = r.u32s()?;
    let n_probes = r.u32()?;
    let entries = read_entries(r, IndexLists::Plain)?;
    Ok(ProbeVolume {
        origin,
        spacing,
        dims,
        slot,
        n_probes,
        entries,
    })
}

fn read_dnrt(r: &mut Reader) -> Result<Vec<crate::dnrt_grid::DnrtGrid>, BundleError> {
    let n = r.u32()? as usize;
    let mut grids = Vec::with_capacity(n.min(r.remaining()));
    for _ in 0..n {
        grids.push(
            crate::dnrt_grid::DnrtGrid::read(r).map_err(|e| BundleError::Invalid(e.to_string()))?,
        );
    }
    Ok(grids)
}
