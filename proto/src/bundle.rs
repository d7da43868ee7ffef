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
//! This file holds the types, encode, decode and validate; beside it, `gather_encoding` (how
//! the DRT section stores the exact gather), `sh_responses` (the `sh` section) and
//! `symmetric_blocks` (blocks instancing a shape through a box symmetry, section kind 14, and
//! their unfolding at load) and `validate` ([`Bundle::validate`], every index, size and rank
//! checked against the data).
//!
//! Invariant: [`Bundle::decode`] returns `Ok` only for a bundle whose every index, size and value
//! is consistent and finite, so the runtime can index without checks; it never panics.

use crate::codec::{
    choose_encoding, read_matrix, u8_step_name, write_matrix_smallest, CodecPolicy, MatrixCodec,
};
use crate::container::{read_sections, write_container, ContainerError, SectionInfo};
use crate::wire::{Reader, WireError, Writer};

mod gather_encoding;
mod sh_responses;
mod symmetric_blocks;
mod validate;
pub use gather_encoding::gather_counts;
pub use sh_responses::{ShEntry, ShResponses};
pub use symmetric_blocks::BlockSymmetry;

pub const BUNDLE_MAGIC: &[u8; 8] = crate::container::MAGIC;
/// Format 2.0: blocks may instance a shape through a box symmetry (section kind 14) and 8-bit
/// matrices may be stored predicted (codec tags 4 and 5). A 1.x reader refuses it by its major
/// version; this reader still reads 1.x bundles (kind 3 blocks, tags 0–3).
pub const BUNDLE_MAJOR: u16 = 2;
pub const BUNDLE_MINOR: u16 = 0;
/// The oldest major version this reader decodes.
pub const OLDEST_READABLE_MAJOR: u16 = 1;
const READABLE_MAJORS: std::ops::RangeInclusive<u16> = OLDEST_READABLE_MAJOR..=BUNDLE_MAJOR;

/// Section kinds.
pub mod section {
    pub const LAYOUT: u32 = 1;
    pub const SHAPES: u32 = 2;
    pub const BLOCKS: u32 = 3;
    pub const TRANSPORT: u32 = 4;
    pub const FULL: u32 = 5;
    pub const DRT: u32 = 6;
    pub const PROBES: u32 = 7;
    /// DNRT grids with `t_j` and `k_j` apart (minor 1). Kind 8 held the paper's `m_j` (minor 0)
    /// and is no longer read: such a bundle decodes without grids.
    pub const DNRT: u32 = 9;
    /// SH incident-radiance responses for normal-mapped surfaces (minor 2).
    pub const SH: u32 = 10;
    /// The DRT section in the layout of minor 2, which adds low-rank entries and direct-light
    /// sources (see [`super::DeltaEntry`]). Written instead of [`DRT`] only when some entry uses
    /// them, so a minor-1 reader skips it and lights the scene by MRT alone.
    pub const DRT_LOW_RANK: u32 = 11;
    /// Where mesh surfaces' texels sit in their own lightmap images (minor 2).
    pub const LIGHTMAP: u32 = 12;
    /// The DRT section of minor 3: the minor-2 layout followed by the block texels whose MRT
    /// light the exact gather replaces ([`super::DrtOps::replaced`]). Written instead of
    /// [`DRT_LOW_RANK`] only when that list is not empty, so an older reader skips it and
    /// lights the scene by MRT alone rather than adding the gather on top of MRT.
    pub const DRT_REPLACING: u32 = 13;
    /// Blocks of format 2: [`BLOCKS`]' records plus each block's box symmetry and closed faces
    /// ([`super::BlockSymmetry`]). Written instead of [`BLOCKS`] by 2.x writers.
    pub const BLOCKS_SYMMETRIC: u32 = 14;
}

/// Report name of a section kind.
pub fn section_name(kind: u32) -> &'static str {
    match kind {
        section::LAYOUT => "layout",
        section::SHAPES => "shapes",
        section::BLOCKS => "blocks",
        section::TRANSPORT => "transport",
        section::FULL => "full",
        section::DRT => "drt",
        section::PROBES => "probes",
        section::DNRT => "dnrt",
        section::SH => "sh",
        section::DRT_LOW_RANK => "drt",
        section::LIGHTMAP => "lightmap",
        section::DRT_REPLACING => "drt",
        section::BLOCKS_SYMMETRIC => "blocks",
        _ => "unknown",
    }
}

fn is_known_section(kind: u32) -> bool {
    section_name(kind) != "unknown"
}

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
    pub fn row(&self, i: usize) -> &[f32] {
        let c = self.cols as usize;
        &self.data[i * c..(i + 1) * c]
    }
    fn write(&self, w: &mut Writer, enc: &mut MatrixEncoder) {
        enc.write(w, self);
    }
    fn read(r: &mut Reader, what: &str) -> Result<Matrix, BundleError> {
        let (rows, cols, data, _codec) = read_matrix(r).map_err(|e| match e {
            WireError::Invalid(m) => BundleError::Invalid(format!("{what}: {m}")),
            e => BundleError::Wire(e),
        })?;
        if let Some(k) = data.iter().position(|x| !x.is_finite()) {
            return Err(BundleError::Invalid(format!(
                "{what}: value {k} is not finite"
            )));
        }
        Ok(Matrix { rows, cols, data })
    }
}

/// Picks each operator matrix's codec by the [`EncodeOptions`] and tallies what it chose.
struct MatrixEncoder {
    /// The policy of the matrices being written now.
    policy: CodecPolicy,
    /// The policy of the transport section's matrices.
    transport_policy: CodecPolicy,
    report: EncodeReport,
}

impl MatrixEncoder {
    fn new(options: &EncodeOptions) -> MatrixEncoder {
        MatrixEncoder {
            policy: options.codec,
            transport_policy: options.transport_codec.unwrap_or(options.codec),
            report: EncodeReport::default(),
        }
    }

    /// Writes the transport section's matrices (inside `write`) under the transport policy.
    fn with_transport_policy(&mut self, write: impl FnOnce(&mut MatrixEncoder)) {
        let operator_policy = std::mem::replace(&mut self.policy, self.transport_policy);
        write(self);
        self.policy = operator_policy;
    }

    fn write(&mut self, w: &mut Writer, m: &Matrix) {
        let (rows, cols) = (m.rows as usize, m.cols as usize);
        let (codec, step, error) = choose_encoding(&m.data, rows, cols, self.policy);
        // Lossless: an 8-bit matrix's q go plain or as prediction residuals, whichever is
        // smaller; both decode to the same values.
        let codec = write_matrix_smallest(w, &m.data, rows, cols, codec, step);
        let name = if codec.is_u8() {
            u8_step_name(step)
        } else {
            codec.name()
        };
        let usage = self.report.codecs.entry(name).or_default();
        usage.matrices += 1;
        usage.predicted += codec.is_predicted() as u64;
        usage.values += (rows * cols) as u64;
        usage.bytes += codec.value_bytes(rows, cols) as u64;
        self.report.max_codec_error = self.report.max_codec_error.max(error);
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
    /// Per codec name (`f32`, `f16`, `u8` or a coarser 8-bit grid's [`u8_step_name`]; plain
    /// and predicted 8-bit matrices count under the same name).
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
}

/// A sparse row-major matrix (CSR) over all texels: the dense one-bounce operator F.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SparseRows {
    pub n: u32,
    pub row_start: Vec<u32>,
    pub cols: Vec<u32>,
    pub values: Vec<f32>,
}

/// A decoded bundle.
#[derive(Clone, Debug, PartialEq)]
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
/// `entries` map block `b` / clutter `c` coefficients to rows `probe · 9 + coefficient`.
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

impl DeltaEntry {
    /// Whether only a minor-2 reader understands this entry.
    pub fn needs_low_rank_format(&self) -> bool {
        self.mix.is_some() || matches!(self.source, DeltaSource::Direct { .. })
    }
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

/// Sparse rows over texels (see [`DrtOps::direct_gather`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TexelGather {
    pub rows: Vec<u32>,
    pub row_start: Vec<u32>,
    pub cols: Vec<u32>,
    pub values: Vec<f32>,
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

fn write_vec3s(w: &mut Writer, v: &[[f32; 3]]) {
    let flat: Vec<f32> = v.iter().flatten().copied().collect();
    w.f32s(&flat);
}

impl Layout {
    pub fn n_texels(&self) -> usize {
        self.positions.len()
    }

    fn write(&self, w: &mut Writer) {
        w.str(&self.scene_name);
        w.u32(self.surfaces.len() as u32);
        for s in &self.surfaces {
            w.str(&s.name);
            w.u32(s.texel_offset);
            w.u32(s.texel_count);
        }
        write_vec3s(w, &self.positions);
        write_vec3s(w, &self.normals);
        write_vec3s(w, &self.albedo);
        let sizes: Vec<f32> = self.texel_size.iter().flatten().copied().collect();
        w.f32s(&sizes);
        w.u32(self.rects.len() as u32);
        for rect in &self.rects {
            w.u8(rect.axis);
            w.f32(rect.coord);
            w.f32(rect.min[0]);
            w.f32(rect.min[1]);
            w.f32(rect.max[0]);
            w.f32(rect.max[1]);
        }
        let flat: Vec<f32> = self.triangles.iter().flatten().flatten().copied().collect();
        w.f32s(&flat);
    }

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
    /// Encodes the bundle losslessly ([`EncodeOptions::default`]).
    pub fn encode(&self) -> Vec<u8> {
        self.encode_with(&EncodeOptions::default()).0
    }

    /// Encodes the bundle with the given codecs and compression.
    pub fn encode_with(&self, options: &EncodeOptions) -> (Vec<u8>, EncodeReport) {
        let mut enc = MatrixEncoder::new(options);
        let sections = self.encode_sections(&mut enc);
        // Always the writer's minor version, whatever sections this bundle has: a streamed
        // prefix (MRT sections only) and the whole bundle must share their header bytes.
        let minor = BUNDLE_MINOR;
        let (bytes, infos) = write_container(BUNDLE_MAJOR, minor, &sections, options.zstd_level);
        let mut report = enc.report;
        report.sections = infos
            .into_iter()
            .map(|i| (section_name(i.kind), i))
            .collect();
        report.total_bytes = bytes.len() as u64;
        (bytes, report)
    }

    /// The uncompressed f32 payload of every section, in file order (what
    /// [`write_container`] frames; for tools and tests that edit sections).
    pub fn raw_sections(&self) -> Vec<(u32, Vec<u8>)> {
        // The default options store every matrix as f32.
        let mut enc = MatrixEncoder::new(&EncodeOptions::default());
        self.encode_sections(&mut enc)
    }

    fn encode_sections(&self, enc: &mut MatrixEncoder) -> Vec<(u32, Vec<u8>)> {
        let mut sections: Vec<(u32, Vec<u8>)> = Vec::new();
        let mut w = Writer::new();
        self.layout.write(&mut w);
        sections.push((section::LAYOUT, w.bytes));
        if !self.surface_atlases.is_empty() {
            let mut w = Writer::new();
            w.u32(self.surface_atlases.len() as u32);
            for a in &self.surface_atlases {
                w.u32(a.surface);
                w.u32(a.width);
                w.u32(a.height);
                w.u32s(&a.texel_xy.iter().flatten().copied().collect::<Vec<_>>());
            }
            sections.push((section::LIGHTMAP, w.bytes));
        }

        let mut w = Writer::new();
        w.u32(self.shapes.len() as u32);
        for s in &self.shapes {
            w.str(&s.key);
            s.u_b.write(&mut w, enc);
            s.t_db.write(&mut w, enc);
            w.u32(s.openings.len() as u32);
            for o in &s.openings {
                w.u8(o.face);
                o.u_r.write(&mut w, enc);
            }
        }
        sections.push((section::SHAPES, w.bytes));

        let mut w = Writer::new();
        symmetric_blocks::write_blocks(&mut w, &self.blocks);
        sections.push((section::BLOCKS_SYMMETRIC, w.bytes));

        if let Some(t) = &self.transport {
            let mut w = Writer::new();
            enc.with_transport_policy(|enc| match t {
                TransportOps::Lightfield(entries) => {
                    w.u8(0);
                    w.u32(entries.len() as u32);
                    for e in entries {
                        w.u32(e.target_block);
                        w.u8(e.target_face);
                        w.u32(e.source_block);
                        e.matrix.write(&mut w, enc);
                    }
                }
                TransportOps::Traced(entries) => {
                    w.u8(1);
                    w.u32(entries.len() as u32);
                    for e in entries {
                        w.u32(e.target_block);
                        w.u32(e.source_block);
                        e.matrix.write(&mut w, enc);
                    }
                }
                TransportOps::Compact(entries) => {
                    w.u8(2);
                    w.u32(entries.len() as u32);
                    for e in entries {
                        w.u32(e.target_block);
                        w.u32s(&e.sources);
                        e.y.write(&mut w, enc);
                        e.z.write(&mut w, enc);
                    }
                }
            });
            sections.push((section::TRANSPORT, w.bytes));
        }
        if let Some(d) = &self.drt {
            let mut w = Writer::new();
            w.u32(d.clutter.len() as u32);
            for c in &d.clutter {
                w.str(&c.id);
                w.u32(c.texel_offset);
                c.t_dc.write(&mut w, enc);
            }
            write_entries(&mut w, &d.entries, enc);
            w.u32s(&d.buried);
            gather_encoding::write_gather(&mut w, d.direct_gather.as_ref());
            let kind = if !d.replaced.is_empty() {
                w.u32s(&d.replaced);
                section::DRT_REPLACING
            } else if d.entries.iter().any(DeltaEntry::needs_low_rank_format) {
                section::DRT_LOW_RANK
            } else {
                section::DRT
            };
            sections.push((kind, w.bytes));
        }
        if let Some(p) = &self.probes {
            let mut w = Writer::new();
            for x in p.origin {
                w.f32(x);
            }
            w.f32(p.spacing);
            for d in p.dims {
                w.u32(d);
            }
            w.u32s(&p.slot);
            w.u32(p.n_probes);
            write_entries(&mut w, &p.entries, enc);
            sections.push((section::PROBES, w.bytes));
        }
        if let Some(grids) = &self.dnrt {
            let mut w = Writer::new();
            w.u32(grids.len() as u32);
            for g in grids {
                g.write(&mut w);
            }
            sections.push((section::DNRT, w.bytes));
        }
        if let Some(sh) = &self.sh {
            let mut w = Writer::new();
            sh_responses::write_sh(&mut w, sh, enc);
            sections.push((section::SH, w.bytes));
        }
        if let Some(f) = &self.full {
            let mut w = Writer::new();
            w.u32(f.n);
            w.u32s(&f.row_start);
            w.u32s(&f.cols);
            w.f32s(&f.values);
            sections.push((section::FULL, w.bytes));
        }

        sections
    }

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
        for (kind, payload) in &sections {
            let mut p = Reader::new(payload);
            match *kind {
                section::LAYOUT => layout = Some(Layout::read(&mut p)?),
                section::SHAPES => shapes = Some(read_shapes(&mut p)?),
                section::BLOCKS => blocks = Some(read_blocks(&mut p)?),
                section::BLOCKS_SYMMETRIC => blocks = Some(symmetric_blocks::read_blocks(&mut p)?),
                section::TRANSPORT => transport = Some(read_transport(&mut p)?),
                section::FULL => full = Some(read_full(&mut p)?),
                section::DRT | section::DRT_LOW_RANK => drt = Some(read_drt(&mut p)?),
                section::DRT_REPLACING => {
                    let mut d = read_drt(&mut p)?;
                    d.replaced = p.u32s()?;
                    drt = Some(d);
                }
                section::PROBES => probes = Some(read_probes(&mut p)?),
                section::DNRT => dnrt = Some(read_dnrt(&mut p)?),
                section::SH => sh = Some(sh_responses::read_sh(&mut p)?),
                section::LIGHTMAP => surface_atlases = read_surface_atlases(&mut p)?,
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

fn read_blocks(r: &mut Reader) -> Result<Vec<BlockOps>, BundleError> {
    let n = r.u32()? as usize;
    let mut out = Vec::with_capacity(n.min(r.remaining() / 12));
    for _ in 0..n {
        out.push(BlockOps {
            id: r.str()?,
            shape: r.u32()?,
            texel_offset: r.u32()?,
            symmetry: None,
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
        2 => {
            let mut out = Vec::with_capacity(n.min(r.remaining() / 30));
            for _ in 0..n {
                out.push(CompactEntry {
                    target_block: r.u32()?,
                    sources: r.u32s()?,
                    y: Matrix::read(r, "transport y")?,
                    z: Matrix::read(r, "transport z")?,
                });
            }
            Ok(TransportOps::Compact(out))
        }
        k => Err(BundleError::Invalid(format!("transport: unknown kind {k}"))),
    }
}

fn read_full(r: &mut Reader) -> Result<SparseRows, BundleError> {
    Ok(SparseRows {
        n: r.u32()?,
        row_start: r.u32s()?,
        cols: r.u32s()?,
        values: r.f32s()?,
    })
}

fn read_drt(r: &mut Reader) -> Result<DrtOps, BundleError> {
    let n_clutter = r.u32()? as usize;
    let mut clutter = Vec::with_capacity(n_clutter.min(r.remaining() / 16));
    for _ in 0..n_clutter {
        clutter.push(ClutterOps {
            id: r.str()?,
            texel_offset: r.u32()?,
            t_dc: Matrix::read(r, "drt clutter")?,
        });
    }
    let entries = read_entries(r)?;
    let buried = r.u32s()?;
    let direct_gather = gather_encoding::read_gather(r)?;
    Ok(DrtOps {
        clutter,
        entries,
        buried,
        direct_gather,
        replaced: Vec::new(),
    })
}

fn write_entries(w: &mut Writer, entries: &[DeltaEntry], enc: &mut MatrixEncoder) {
    w.u32(entries.len() as u32);
    for e in entries {
        w.u32s(&e.rows);
        // Bit 7 of the source kind: a `mix` matrix follows the entry's matrix.
        write_source(w, e.source, if e.mix.is_some() { 0x80 } else { 0 });
        e.matrix.write(w, enc);
        if let Some(mix) = &e.mix {
            mix.write(w, enc);
        }
    }
}

/// Writes a delta source: its kind byte (0 block, 1 clutter, 2 direct-light range) with `flags`
/// or-ed into bits 4–7, then its index or `first, count`.
pub(crate) fn write_source(w: &mut Writer, source: DeltaSource, flags: u8) {
    match source {
        DeltaSource::Block(b) => {
            w.u8(flags);
            w.u32(b);
        }
        DeltaSource::Clutter(c) => {
            w.u8(1 | flags);
            w.u32(c);
        }
        DeltaSource::Direct { first, count } => {
            w.u8(2 | flags);
            w.u32(first);
            w.u32(count);
        }
    }
}

/// Reads what [`write_source`] wrote: the source and the kind byte's flag bits.
pub(crate) fn read_source(r: &mut Reader, what: &str) -> Result<(DeltaSource, u8), BundleError> {
    let kind = r.u8()?;
    let source = match kind & 0x0f {
        0 => DeltaSource::Block(r.u32()?),
        1 => DeltaSource::Clutter(r.u32()?),
        2 => DeltaSource::Direct {
            first: r.u32()?,
            count: r.u32()?,
        },
        k => {
            return Err(BundleError::Invalid(format!(
                "{what}: unknown source kind {k}"
            )))
        }
    };
    Ok((source, kind & 0xf0))
}

fn read_entries(r: &mut Reader) -> Result<Vec<DeltaEntry>, BundleError> {
    let n_entries = r.u32()? as usize;
    let mut entries = Vec::with_capacity(n_entries.min(r.remaining() / 24));
    for _ in 0..n_entries {
        let rows = r.u32s()?;
        let (source, flags) = read_source(r, "delta entry")?;
        if flags & !0x80 != 0 {
            return Err(BundleError::Invalid(format!(
                "delta entry: unknown source flags {flags:#x}"
            )));
        }
        let matrix = Matrix::read(r, "delta entry")?;
        let mix = if flags & 0x80 != 0 {
            Some(Matrix::read(r, "delta entry mix")?)
        } else {
            None
        };
        entries.push(DeltaEntry {
            rows,
            source,
            matrix,
            mix,
        });
    }
    Ok(entries)
}

fn read_probes(r: &mut Reader) -> Result<ProbeVolume, BundleError> {
    let origin = [r.f32()?, r.f32()?, r.f32()?];
    let spacing = r.f32()?;
    let dims = [r.u32()?, r.u32()?, r.u32()?];
    let slot = r.u32s()?;
    let n_probes = r.u32()?;
    let entries = read_entries(r)?;
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
