//! The operator bundle: everything a client needs to turn direct light into indirect light.
//!
//! The bytes are a [`crate::container`] (magic, version, compressed and checksummed sections,
//! table of contents; specified in `docs/bundle-format.md`). Sections come in the order a client
//! can use them: layout, shape operators, block instances and MRT transport light the scene;
//! the DRT and probe sections add clutter and dynamic-object lighting; the `sh` section (minor 2,
//! [`ShResponses`], only when the scene asks) per-texel SH incident radiance for normal-mapped
//! surfaces; `full` (dense reference operator) comes last. A reader skips section kinds it does
//! not know (newer minor version); a different major version is refused.
//!
//! Operator matrices are row-major, stored in the codec [`EncodeOptions`] picks per matrix
//! (f32, f16 or 8-bit, see [`crate::codec`]) and decoded to f32. Shapes: `U_b` is texels × r,
//! `T_d→b` is r × texels, `U_r` per opening is texels × q. Operators are albedo-free: the client
//! multiplies the receiving texel's albedo in at the end (`l_ind = ρ ⊙ (U_b b + …)`).
//!
//! # Layout
//! This file holds the format version, the types (the decoded [`Bundle`] and every section's
//! payload, [`EncodeOptions`] and [`EncodeReport`], [`BundleError`]) and re-exports what the
//! files beside it define, so every public path is `bundle::X`. One concept per file:
//! - `sections`: the section kinds ([`section`]), their report names ([`section_name`]) and
//!   which kinds this reader knows.
//! - `write`: [`Bundle::encode`], [`Bundle::encode_with`], [`Bundle::raw_sections`]: every
//!   section's payload in file order, framed by the container.
//! - `read`: [`Bundle::decode`], [`Bundle::decode_prefix`]: sections back into a [`Bundle`]
//!   (what 2.x writers write and every section kind 1.x wrote that 2.x still writes), validated.
//! - `legacy_1x`: reading what only 1.x bundles hold (kind 3 blocks, the CSR form of the exact
//!   gather); read-only, nothing writes it.
//! - `matrix_codec`: one operator [`Matrix`] on the wire through [`crate::codec`]: the codec the
//!   [`EncodeOptions`] pick per matrix, tallied into the [`EncodeReport`], and the finite check
//!   on reading.
//! - `delta_entries`: the [`DeltaEntry`] lists of the DRT and probe sections and the
//!   [`DeltaSource`] encoding the `sh` section shares.
//! - `gather_encoding`: how the DRT section stores the exact gather ([`TexelGather`]), its
//!   weights as counts of one byte, escaped past 255 in kind 20.
//! - `gather_model`: the exact gather's modelled form (section kind 23): each row's columns and
//!   hit counts range-coded under contexts from the rows next to and above it.
//! - `gather_tiles`: the tiles of texels a gather column may read the mean of ([`GatherTiles`],
//!   section kind 21).
//! - `index_lists`: the DRT section's texel index lists as `u32s` or packed as varints of
//!   their steps (section kind 22).
//! - `sh_responses`: the `sh` section ([`ShResponses`]).
//! - `dynamic_shapes`: the dynamic objects' triangles in their own frames (section kind 19,
//!   [`DynamicShape`]), for their direct shadows.
//! - `rooms`: the level's rooms (section kind 15, [`Rooms`]): each block's box, where each face
//!   leads and the rooms each layout surface lies in, for a client's light reach.
//! - `symmetric_blocks`: blocks instancing a shape through a box symmetry (section kind 14,
//!   [`BlockSymmetry`]) and their unfolding at load.
//! - `source_bases`: compact transport with shared source bases (transport kind 3,
//!   [`SourceBases`]) and its unfolding at load.
//! - `validate`: [`Bundle::validate`], every index, size and rank checked against the data.
//!
//! Invariant: [`Bundle::decode`] returns `Ok` only for a bundle whose every index, size and value
//! is consistent and finite, so the runtime can index without checks; it never panics.

use crate::codec::{CodecPolicy, MatrixCodec};
use crate::container::{ContainerError, SectionInfo};
use crate::wire::WireError;

mod delta_entries;
mod dynamic_shapes;
mod gather_encoding;
mod gather_model;
mod gather_tiles;
mod index_lists;
mod legacy_1x;
mod matrix_codec;
mod read;
mod rooms;
mod sections;
mod sh_responses;
mod source_bases;
mod symmetric_blocks;
mod validate;
mod write;
pub use dynamic_shapes::DynamicShape;
pub use gather_encoding::{gather_counts, gather_counts_u16};
pub use gather_tiles::GatherTiles;
pub use matrix_codec::{EncodingMemo, MatrixEncoding};
pub use rooms::{FaceLink, Room, Rooms, SurfacePlace};
pub use sections::{section, section_name};
pub use sh_responses::{ShEntry, ShResponses};
pub use source_bases::{SourceBases, SourceBasis};
pub use symmetric_blocks::BlockSymmetry;

pub const BUNDLE_MAGIC: &[u8; 8] = crate::container::MAGIC;
/// Format 2.0: blocks may instance a shape through a box symmetry (section kind 14) and 8-bit
/// matrices may be stored predicted (codec tags 4 and 5). A 1.x reader refuses it by its major
/// version; this reader still reads 1.x bundles (kind 3 blocks, tags 0–3). Minor 1 adds the
/// rooms section (kind 15), which a 2.0 reader skips. Minor 2 adds compact transport with
/// shared source bases ([`SourceBases`], transport kind 3) in a section of its own (kind 16),
/// written instead of kind 4 when some source is factored: a 2.0 or 2.1 reader skips it and
/// lights the level without light between blocks. Minor 3 adds the probe volume with low-rank
/// entries (kind 17), written instead of kind 7 when some entry is factored, and DNRT grids with
/// their 8-bit values planar and differenced (kind 18, codec tag 3), written instead of kind 9
/// when some grid is 8-bit: a 2.2 or older reader skips them and reads the bundle without a
/// probe volume or without grids. Minor 4 adds the dynamic objects' shapes (kind 19), which a
/// 2.3 or older reader skips (it shades direct light without the objects' shadows). Minor 5
/// adds the DRT section whose exact gather keeps counts over 255 as escaped bytes (kind 20),
/// written instead of kind 13 when some count exceeds a byte: a 2.4 or older reader skips it
/// and lights the scene by MRT alone. Minor 6 adds the DRT section whose exact gather reads tiles
/// of texels ([`GatherTiles`], kind 21), written instead of kinds 13 and 20 when the gather has
/// tiles: a 2.5 or older reader skips it and lights the scene by MRT alone. Minor 7 adds the DRT
/// section whose texel index lists are packed as varints of their steps (kind 22), the only DRT
/// kind it writes: a 2.6 or older reader skips it and lights the scene by MRT alone. Minor 8
/// adds the DRT section whose exact gather may be range-coded under contexts from its
/// neighbouring rows (gather form 3, kind 23), the only DRT kind it writes: a 2.7 or older
/// reader skips it and lights the scene by MRT alone.
pub const BUNDLE_MAJOR: u16 = 2;
pub const BUNDLE_MINOR: u16 = 8;
/// The oldest major version this reader decodes.
pub const OLDEST_READABLE_MAJOR: u16 = 1;
const READABLE_MAJORS: std::ops::RangeInclusive<u16> = OLDEST_READABLE_MAJOR..=BUNDLE_MAJOR;

/// What [`Bundle::decode_prefix`] could use of a bundle still arriving.
#[derive(Clone, Debug, PartialEq)]
pub struct PartialBundle {
    pub bundle: Bundle,
    /// Whether the whole bundle (through its table of contents) was there.
    pub complete: bool,
    /// Names of the sections decoded, in file order.
    pub present: Vec<&'static str>,
}

/// A dense row-major f32 matrix.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Matrix {
    pub rows: u32,
    pub cols: u32,
    pub data: Vec<f32>,
}

impl Matrix {
    pub fn zeros(rows: usize, cols: usize) -> Matrix {
        Matrix {
            rows: rows as u32,
            cols: cols as u32,
            data: vec![0.0; rows * cols],
        }
    }
    /// The matrix with `value(i, j)` at row i, column j.
    pub fn from_fn(rows: u32, cols: u32, value: impl Fn(u32, u32) -> f32) -> Matrix {
        let data = (0..rows)
            .flat_map(|i| (0..cols).map(move |j| (i, j)))
            .map(|(i, j)| value(i, j))
            .collect();
        Matrix { rows, cols, data }
    }
    pub fn row(&self, i: usize) -> &[f32] {
        let c = self.cols as usize;
        &self.data[i * c..(i + 1) * c]
    }
}

/// How [`Bundle::encode_with`] stores a bundle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EncodeOptions {
    /// Codec of every operator matrix (fixed, or chosen per matrix from an error budget).
    pub codec: CodecPolicy,
    /// Codec of the transport section's matrices, when it differs from `codec`. Transport into
    /// a block stacks the coefficients of all its source blocks in one matrix, so a relative
    /// budget is spent on the strongest source and the weak ones, which are all the light a
    /// block far from every light gets, keep the least precision; they may need a tighter one.
    pub transport_codec: Option<CodecPolicy>,
    /// zstd level for section payloads (0: store raw). A payload is stored raw whenever
    /// compression would not shrink it.
    pub zstd_level: i32,
}

impl Default for EncodeOptions {
    /// Lossless: f32 operators, zstd level 3.
    fn default() -> Self {
        EncodeOptions {
            codec: CodecPolicy::Fixed(MatrixCodec::F32),
            transport_codec: None,
            zstd_level: 3,
        }
    }
}

/// How many operator values went into one codec.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CodecUsage {
    pub matrices: u64,
    /// Of those, 8-bit matrices stored as prediction residuals (codec tags 4 and 5).
    pub predicted: u64,
    pub values: u64,
    /// Bytes of the values before compression.
    pub bytes: u64,
}

/// What [`Bundle::encode_with`] wrote.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EncodeReport {
    /// Per section in file order: its name and sizes.
    pub sections: Vec<(&'static str, SectionInfo)>,
    /// Per codec name (`f32`, `f16`, or an 8-bit grid's
    /// [`u8_grid_name`](crate::codec::u8_grid_name); plain and predicted 8-bit matrices count
    /// under the same name).
    pub codecs: std::collections::BTreeMap<&'static str, CodecUsage>,
    /// Largest relative RMS error a codec added to one matrix.
    pub max_codec_error: f64,
    /// Bytes of the whole file.
    pub total_bytes: u64,
}

/// A named surface and its texel range in the layout.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceInfo {
    /// `block:<id>/<face>` or `clutter:<id>`.
    pub name: String,
    pub texel_offset: u32,
    pub texel_count: u32,
}

/// An axis-aligned rectangle occluder (a block wall or a clutter box face).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rect {
    pub axis: u8,
    pub coord: f32,
    pub min: [f32; 2],
    pub max: [f32; 2],
}

/// Texels and the occluding geometry (for the client's shadow rays).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Layout {
    pub scene_name: String,
    pub surfaces: Vec<SurfaceInfo>,
    /// Texel centres (world, metres).
    pub positions: Vec<[f32; 3]>,
    /// Unit normals on the lit side.
    pub normals: Vec<[f32; 3]>,
    pub albedo: Vec<[f32; 3]>,
    /// Texel size (metres) along the two tangent axes of the normal's dominant axis
    /// (ascending axis order); lets a client average direct light over a texel.
    pub texel_size: Vec<[f32; 2]>,
    pub rects: Vec<Rect>,
    pub triangles: Vec<[[f32; 3]; 3]>,
}

/// Response to light arriving through one opening of a shape.
#[derive(Clone, Debug, PartialEq)]
pub struct OpeningOps {
    /// Face index in `-x +x -y +y -z +z` order.
    pub face: u8,
    /// texels × q.
    pub u_r: Matrix,
}

/// Scene-independent operators of one shape (stored once however many blocks use it).
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeOps {
    /// Content key of the shape in the operator cache.
    pub key: String,
    /// texels × r.
    pub u_b: Matrix,
    /// r × texels.
    pub t_db: Matrix,
    pub openings: Vec<OpeningOps>,
}

/// A block: which shape it instances and where its texels are.
#[derive(Clone, Debug, PartialEq)]
pub struct BlockOps {
    pub id: String,
    pub shape: u32,
    pub texel_offset: u32,
    /// The box symmetry taking the block's frame to its shape's (None: the identity): block
    /// texel `x` is the shape's texel `perm[x]` ([`BlockSymmetry::texel_permutation`]).
    pub symmetry: Option<BlockSymmetry>,
}

/// Lightfield transport: reduced incoming lightfield at `(target_block, target_face)` from
/// `source_block`'s coefficients, `r_in = Σ matrix · b_source` (q × r_source).
#[derive(Clone, Debug, PartialEq)]
pub struct PropEntry {
    pub target_block: u32,
    pub target_face: u8,
    pub source_block: u32,
    pub matrix: Matrix,
}

/// Traced transport: indirect on `target_block`'s texels from `source_block`'s coefficients
/// (texels × r_source).
#[derive(Clone, Debug, PartialEq)]
pub struct TracedEntry {
    pub target_block: u32,
    pub source_block: u32,
    pub matrix: Matrix,
}

/// Compacted transport into one block: `l_ind[target texels] += y · (z · [b_s for s in
/// sources])`, the sources' coefficients stacked in `sources` order (ascending).
#[derive(Clone, Debug, PartialEq)]
pub struct CompactEntry {
    pub target_block: u32,
    pub sources: Vec<u32>,
    /// texels_target × k.
    pub y: Matrix,
    /// k × Σ r_source.
    pub z: Matrix,
}

/// Inter-block transport.
#[derive(Clone, Debug, PartialEq)]
pub enum TransportOps {
    Lightfield(Vec<PropEntry>),
    Traced(Vec<TracedEntry>),
    /// One low-rank operator per receiving block (entries ascending by target, one each).
    Compact(Vec<CompactEntry>),
    /// [`TransportOps::Compact`] with shared source bases (kind 3, minor 2); a runtime
    /// unfolds it at load ([`Bundle::unfold_source_bases`]).
    Factored(SourceBases),
}

/// A sparse row-major matrix (CSR) over all texels: the dense one-bounce operator F.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SparseRows {
    pub n: u32,
    pub row_start: Vec<u32>,
    pub cols: Vec<u32>,
    pub values: Vec<f32>,
}

/// A decoded bundle. `Bundle::default()` is the empty bundle (no texels, no operators), the
/// base hand-built bundles fill in.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Bundle {
    pub layout: Layout,
    pub shapes: Vec<ShapeOps>,
    pub blocks: Vec<BlockOps>,
    pub transport: Option<TransportOps>,
    pub full: Option<SparseRows>,
    /// Delta Radiance Transfer operators (clutter); absent in MRT-only bundles.
    pub drt: Option<DrtOps>,
    /// U_dyn: SH radiance probes from b and c, for dynamic objects (and MRT's clutter shading).
    pub probes: Option<ProbeVolume>,
    /// DNRT transfer grids, one per dynamic object (`crate::dnrt_grid`).
    pub dnrt: Option<Vec<crate::dnrt_grid::DnrtGrid>>,
    /// SH incident-radiance responses per lit texel (`settings.sh_responses`; minor 2).
    pub sh: Option<ShResponses>,
    /// The lightmap atlas of each mesh surface (mesh clutter), ascending by surface; empty
    /// when the scene has none (and in bundles before minor 2).
    pub surface_atlases: Vec<SurfaceAtlas>,
    /// The level's rooms, for a client's light reach (format 2.1; `None` in older bundles and
    /// in bundles built without a scene).
    pub rooms: Option<Rooms>,
    /// Each dynamic object's triangles in its own frame, for its direct shadows (format 2.4;
    /// empty without dynamic objects and in older bundles).
    pub dynamic_shapes: Vec<DynamicShape>,
}

/// Where the texels of one layout surface sit in that surface's own lightmap image: texel `k`
/// of the surface at column `texel_xy[k][0]`, row `texel_xy[k][1]` (rows top to bottom) of a
/// `width × height` image; cells no texel lands in are empty.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceAtlas {
    /// Index into `Layout::surfaces`.
    pub surface: u32,
    pub width: u32,
    pub height: u32,
    pub texel_xy: Vec<[u32; 2]>,
}

/// A regular grid of SH radiance probes (`crate::sh` convention, 9 coefficients per channel).
/// Grid point `(i, j, k)` sits at `origin + spacing · (i, j, k)`; `slot[(k·ny + j)·nx + i]` is
/// its probe index, or `u32::MAX` where there is no probe (outside the blocks, inside clutter).
/// `entries` map block `b` / clutter `c` coefficients to rows `probe · 9 + coefficient`; an
/// entry with a `mix` is low-rank, `matrix · (mix · x)` (format 2.3, section kind 17).
#[derive(Clone, Debug, PartialEq)]
pub struct ProbeVolume {
    pub origin: [f32; 3],
    pub spacing: f32,
    pub dims: [u32; 3],
    pub slot: Vec<u32>,
    pub n_probes: u32,
    pub entries: Vec<DeltaEntry>,
}

/// Where the coefficients a delta operator multiplies come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeltaSource {
    /// A block's `b` (r coefficients per channel).
    Block(u32),
    /// A clutter object's `c` (m coefficients per channel).
    Clutter(u32),
    /// The direct light of texels `first .. first + count` (the exact clutter gather in
    /// low-rank form; minor 2).
    Direct { first: u32, count: u32 },
}

/// Rows of a delta operator: `out[rows[i]] += matrix.row(i) · coefficients(source)` for each
/// channel, or with `mix` (a low-rank entry, minor 2) `out[rows[i]] += matrix.row(i) · (mix ·
/// coefficients(source))`. `rows` are global texel indices (ascending, unique). This one form carries ΔU_b
/// (delta occlusion, source = block), ΔU_c (delta reflection, source = clutter), C_b (clutter
/// gather, rows on clutter, source = block) and clutter-to-clutter bounce (source = clutter).
#[derive(Clone, Debug, PartialEq)]
pub struct DeltaEntry {
    pub rows: Vec<u32>,
    pub source: DeltaSource,
    /// rows.len() × (r or m), or rows.len() × k with `mix`.
    pub matrix: Matrix,
    /// k × (r or m): the right factor of a low-rank entry.
    pub mix: Option<Matrix>,
}

/// Direct light on one clutter object projected to its basis: `c = t_dc · l_d[texels]`.
#[derive(Clone, Debug, PartialEq)]
pub struct ClutterOps {
    pub id: String,
    pub texel_offset: u32,
    /// m × texel count.
    pub t_dc: Matrix,
}

/// The DRT section.
#[derive(Clone, Debug, PartialEq)]
pub struct DrtOps {
    pub clutter: Vec<ClutterOps>,
    pub entries: Vec<DeltaEntry>,
    /// Texels buried in or under geometry (their values are inpainted).
    pub buried: Vec<u32>,
    /// Exact gather onto clutter texels from the direct light of the texels their rays hit
    /// (`clutter_gather: exact`): `out[rows[i]] += Σ_k values[k] · l_d[cols[k]]` over
    /// `row_start[i]..row_start[i+1]`, albedo-free. Replaces C_b's implicit lights, which cannot
    /// hold the clutter's own shadow on the floor next to it (the weakness DRT §6 names).
    /// With `scene_gather: exact` it also has rows on block texels near clutter.
    pub direct_gather: Option<TexelGather>,
    /// Block texels (ascending) whose MRT light is dropped before the DRT terms are added: near
    /// clutter with `scene_gather: exact`, their indirect light is the gather alone (rows of
    /// `direct_gather`, or `Direct` entries after low-rank compaction). Minor 3; empty otherwise.
    pub replaced: Vec<u32>,
}

/// Sparse rows over texels (see [`DrtOps::direct_gather`]); a column `n_texels + i` reads the
/// mean direct light of tile `i` of `tiles` (format 2.6, [`GatherTiles`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TexelGather {
    pub rows: Vec<u32>,
    pub row_start: Vec<u32>,
    pub cols: Vec<u32>,
    pub values: Vec<f32>,
    pub tiles: GatherTiles,
}

/// Why bytes are not a usable bundle.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BundleError {
    #[error(transparent)]
    Container(#[from] ContainerError),
    #[error("bundle is missing its {0} section")]
    Missing(&'static str),
    #[error("bundle: {0}")]
    Invalid(String),
    #[error("bundle: {0}")]
    Wire(#[from] WireError),
}

impl Layout {
    pub fn n_texels(&self) -> usize {
        self.positions.len()
    }

    /// Per surface, the index (RESULT.json's `index`, within the surface's name) of its first
    /// texel: the texels of the surfaces before it with the same name. A name appears more than
    /// once when the engine baked a long block as pieces (each piece's face is a surface named
    /// after the block's face); otherwise every surface starts at 0.
    pub fn surface_first_index(&self) -> Vec<u32> {
        let mut seen: std::collections::HashMap<&str, u32> = std::collections::HashMap::new();
        self.surfaces
            .iter()
            .map(|s| {
                let next = seen.entry(s.name.as_str()).or_insert(0);
                let first = *next;
                *next += s.texel_count;
                first
            })
            .collect()
    }
}
