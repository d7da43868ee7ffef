//! The operator bundle: everything a client needs to turn direct light into indirect light.
//!
//! File layout (all little-endian): magic `LFBUNDLE`, major u16, minor u16, section count u32,
//! then per section a header (kind u32, byte length u64, FNV-1a checksum u64) and its payload.
//! Sections come in the order a client can use them: layout, shape operators, block instances,
//! transport, then optional extras (the dense `full` operator). A reader skips section kinds it
//! does not know (newer minor version); a newer major version is refused.
//!
//! Matrices are row-major f32. Shapes: `U_b` is texels × r, `T_d→b` is r × texels, `U_r` per
//! opening is texels × q. Operators are albedo-free: the client multiplies the receiving texel's
//! albedo in at the end (`l_ind = ρ ⊙ (U_b b + …)`).
//!
//! Invariant: [`Bundle::decode`] returns `Ok` only for a bundle whose every index, size and value
//! is consistent and finite, so the runtime can index without checks; it never panics.

use crate::wire::{checksum, Reader, WireError, Writer};

pub const BUNDLE_MAGIC: &[u8; 8] = b"LFBUNDLE";
pub const BUNDLE_MAJOR: u16 = 0;
pub const BUNDLE_MINOR: u16 = 3;

/// Section kinds.
pub mod section {
    pub const LAYOUT: u32 = 1;
    pub const SHAPES: u32 = 2;
    pub const BLOCKS: u32 = 3;
    pub const TRANSPORT: u32 = 4;
    pub const FULL: u32 = 5;
    pub const DRT: u32 = 6;
    pub const PROBES: u32 = 7;
    pub const DNRT: u32 = 8;
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
    fn write(&self, w: &mut Writer) {
        w.u32(self.rows);
        w.u32(self.cols);
        w.f32s(&self.data);
    }
    fn read(r: &mut Reader, what: &str) -> Result<Matrix, BundleError> {
        let rows = r.u32()?;
        let cols = r.u32()?;
        let data = r.f32s()?;
        if rows as u64 * cols as u64 != data.len() as u64 {
            return Err(BundleError::Invalid(format!(
                "{what}: {rows}×{cols} matrix holds {} values",
                data.len()
            )));
        }
        if let Some(k) = data.iter().position(|x| !x.is_finite()) {
            return Err(BundleError::Invalid(format!(
                "{what}: value {k} is not finite"
            )));
        }
        Ok(Matrix { rows, cols, data })
    }
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

/// Inter-block transport.
#[derive(Clone, Debug, PartialEq)]
pub enum TransportOps {
    Lightfield(Vec<PropEntry>),
    Traced(Vec<TracedEntry>),
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
}

/// Rows of a delta operator: `out[rows[i]] += matrix.row(i) · coefficients(source)` for each
/// channel. `rows` are global texel indices (ascending, unique). This one form carries ΔU_b
/// (delta occlusion, source = block), ΔU_c (delta reflection, source = clutter), C_b (clutter
/// gather, rows on clutter, source = block) and clutter-to-clutter bounce (source = clutter).
#[derive(Clone, Debug, PartialEq)]
pub struct DeltaEntry {
    pub rows: Vec<u32>,
    pub source: DeltaSource,
    /// rows.len() × (r or m).
    pub matrix: Matrix,
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
    pub direct_gather: Option<TexelGather>,
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
    #[error("not a lightfarm bundle (bad magic)")]
    Magic,
    #[error(
        "bundle major version {0} is newer than this reader ({BUNDLE_MAJOR}); update the client"
    )]
    Version(u16),
    #[error("section {kind}: checksum mismatch (corrupt bundle)")]
    Checksum { kind: u32 },
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
    /// Encodes the bundle.
    pub fn encode(&self) -> Vec<u8> {
        let sections = self.encode_sections();
        let mut out = Writer::new();
        out.bytes.extend_from_slice(BUNDLE_MAGIC);
        out.bytes.extend_from_slice(&BUNDLE_MAJOR.to_le_bytes());
        out.bytes.extend_from_slice(&BUNDLE_MINOR.to_le_bytes());
        out.u32(sections.len() as u32);
        for (kind, payload) in sections {
            out.u32(kind);
            out.u64(payload.len() as u64);
            out.u64(checksum(&payload));
            out.bytes.extend_from_slice(&payload);
        }
        out.bytes
    }

    /// Payload bytes per section kind, in file order (for size reports).
    pub fn section_sizes(&self) -> Vec<(&'static str, usize)> {
        let name = |k: u32| match k {
            section::LAYOUT => "layout",
            section::SHAPES => "shapes",
            section::BLOCKS => "blocks",
            section::TRANSPORT => "transport",
            section::FULL => "full",
            section::DRT => "drt",
            section::PROBES => "probes",
            section::DNRT => "dnrt",
            _ => "unknown",
        };
        self.encode_sections()
            .iter()
            .map(|(k, p)| (name(*k), p.len()))
            .collect()
    }

    fn encode_sections(&self) -> Vec<(u32, Vec<u8>)> {
        let mut sections: Vec<(u32, Vec<u8>)> = Vec::new();
        let mut w = Writer::new();
        self.layout.write(&mut w);
        sections.push((section::LAYOUT, w.bytes));

        let mut w = Writer::new();
        w.u32(self.shapes.len() as u32);
        for s in &self.shapes {
            w.str(&s.key);
            s.u_b.write(&mut w);
            s.t_db.write(&mut w);
            w.u32(s.openings.len() as u32);
            for o in &s.openings {
                w.u8(o.face);
                o.u_r.write(&mut w);
            }
        }
        sections.push((section::SHAPES, w.bytes));

        let mut w = Writer::new();
        w.u32(self.blocks.len() as u32);
        for b in &self.blocks {
            w.str(&b.id);
            w.u32(b.shape);
            w.u32(b.texel_offset);
        }
        sections.push((section::BLOCKS, w.bytes));

        if let Some(t) = &self.transport {
            let mut w = Writer::new();
            match t {
                TransportOps::Lightfield(entries) => {
                    w.u8(0);
                    w.u32(entries.len() as u32);
                    for e in entries {
                        w.u32(e.target_block);
                        w.u8(e.target_face);
                        w.u32(e.source_block);
                        e.matrix.write(&mut w);
                    }
                }
                TransportOps::Traced(entries) => {
                    w.u8(1);
                    w.u32(entries.len() as u32);
                    for e in entries {
                        w.u32(e.target_block);
                        w.u32(e.source_block);
                        e.matrix.write(&mut w);
                    }
                }
            }
            sections.push((section::TRANSPORT, w.bytes));
        }
        if let Some(d) = &self.drt {
            let mut w = Writer::new();
            w.u32(d.clutter.len() as u32);
            for c in &d.clutter {
                w.str(&c.id);
                w.u32(c.texel_offset);
                c.t_dc.write(&mut w);
            }
            write_entries(&mut w, &d.entries);
            w.u32s(&d.buried);
            match &d.direct_gather {
                Some(g) => {
                    w.u8(1);
                    w.u32s(&g.rows);
                    w.u32s(&g.row_start);
                    w.u32s(&g.cols);
                    w.f32s(&g.values);
                }
                None => w.u8(0),
            }
            sections.push((section::DRT, w.bytes));
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
            write_entries(&mut w, &p.entries);
            sections.push((section::PROBES, w.bytes));
        }
        if let Some(f) = &self.full {
            let mut w = Writer::new();
            w.u32(f.n);
            w.u32s(&f.row_start);
            w.u32s(&f.cols);
            w.f32s(&f.values);
            sections.push((section::FULL, w.bytes));
        }
        if let Some(grids) = &self.dnrt {
            let mut w = Writer::new();
            w.u32(grids.len() as u32);
            for g in grids {
                g.write(&mut w);
            }
            sections.push((section::DNRT, w.bytes));
        }

        sections
    }

    /// Decodes and validates a bundle. Any byte string gives `Ok` or `Err`, never a panic.
    pub fn decode(bytes: &[u8]) -> Result<Bundle, BundleError> {
        let mut r = Reader::new(bytes);
        if r.take(8).map_err(|_| BundleError::Magic)? != BUNDLE_MAGIC {
            return Err(BundleError::Magic);
        }
        let major = u16::from_le_bytes(r.take(2)?.try_into().unwrap());
        let _minor = u16::from_le_bytes(r.take(2)?.try_into().unwrap());
        if major != BUNDLE_MAJOR {
            return Err(BundleError::Version(major));
        }
        let n_sections = r.u32()?;
        let (mut layout, mut shapes, mut blocks, mut transport, mut full, mut drt, mut probes) =
            (None, None, None, None, None, None, None);
        let mut dnrt = None;
        for _ in 0..n_sections {
            let kind = r.u32()?;
            let len = r.u64()?;
            let sum = r.u64()?;
            if len > r.remaining() as u64 {
                return Err(BundleError::Wire(WireError::Truncated {
                    offset: r.position(),
                    needed: len.min(usize::MAX as u64) as usize,
                    available: r.remaining(),
                }));
            }
            let payload = r.take(len as usize)?;
            if checksum(payload) != sum {
                return Err(BundleError::Checksum { kind });
            }
            let mut p = Reader::new(payload);
            match kind {
                section::LAYOUT => layout = Some(Layout::read(&mut p)?),
                section::SHAPES => shapes = Some(read_shapes(&mut p)?),
                section::BLOCKS => blocks = Some(read_blocks(&mut p)?),
                section::TRANSPORT => transport = Some(read_transport(&mut p)?),
                section::FULL => full = Some(read_full(&mut p)?),
                section::DRT => drt = Some(read_drt(&mut p)?),
                section::PROBES => probes = Some(read_probes(&mut p)?),
                section::DNRT => dnrt = Some(read_dnrt(&mut p)?),
                _ => {} // a newer minor version's section: skip
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
        };
        bundle.validate()?;
        Ok(bundle)
    }

    /// Checks every index, size and rank against the data (what `decode` runs).
    pub fn validate(&self) -> Result<(), BundleError> {
        let bad = |m: String| Err(BundleError::Invalid(m));
        let n_texels = self.layout.n_texels() as u64;
        // What decoding guarantees by construction, re-checked for bundles built by hand.
        let layout = &self.layout;
        let n = layout.positions.len();
        if layout.normals.len() != n || layout.albedo.len() != n || layout.texel_size.len() != n {
            return bad(
                "layout: positions, normals, albedo and texel sizes differ in length".into(),
            );
        }
        let mut next = 0u64;
        for surface in &layout.surfaces {
            if surface.texel_offset as u64 != next {
                return bad(format!(
                    "layout: surface {} is not contiguous",
                    surface.name
                ));
            }
            next += surface.texel_count as u64;
        }
        if next != n as u64 {
            return bad("layout: surfaces do not cover the texels".into());
        }
        let mut matrices: Vec<&Matrix> = Vec::new();
        for s in &self.shapes {
            matrices.extend([&s.u_b, &s.t_db]);
            matrices.extend(s.openings.iter().map(|o| &o.u_r));
        }
        match &self.transport {
            Some(TransportOps::Lightfield(e)) => matrices.extend(e.iter().map(|e| &e.matrix)),
            Some(TransportOps::Traced(e)) => matrices.extend(e.iter().map(|e| &e.matrix)),
            None => {}
        }
        if let Some(d) = &self.drt {
            matrices.extend(d.clutter.iter().map(|c| &c.t_dc));
            matrices.extend(d.entries.iter().map(|e| &e.matrix));
        }
        if let Some(p) = &self.probes {
            matrices.extend(p.entries.iter().map(|e| &e.matrix));
        }
        if matrices
            .iter()
            .any(|m| m.data.len() as u64 != m.rows as u64 * m.cols as u64)
        {
            return bad("a matrix holds the wrong number of values".into());
        }
        for (k, s) in self.shapes.iter().enumerate() {
            let n = s.u_b.rows;
            if s.t_db.cols != n || s.t_db.rows != s.u_b.cols {
                return bad(format!(
                    "shape {k}: U_b is {}×{}, T_d→b is {}×{}",
                    s.u_b.rows, s.u_b.cols, s.t_db.rows, s.t_db.cols
                ));
            }
            // Ranks never exceed texel counts, so scratch sizes are bounded by real data.
            if s.u_b.cols > n || n as u64 > n_texels {
                return bad(format!(
                    "shape {k}: rank {} exceeds its {n} texels",
                    s.u_b.cols
                ));
            }
            for o in &s.openings {
                if o.face > 5 || o.u_r.rows != n || o.u_r.cols > n {
                    return bad(format!(
                        "shape {k}: opening operator does not match the shape"
                    ));
                }
            }
        }
        for b in &self.blocks {
            let Some(shape) = self.shapes.get(b.shape as usize) else {
                return bad(format!("block {}: shape {} does not exist", b.id, b.shape));
            };
            if b.texel_offset as u64 + shape.u_b.rows as u64 > n_texels {
                return bad(format!("block {}: texel range past the layout", b.id));
            }
        }
        let block_shape = |i: u32| -> Option<&ShapeOps> {
            self.blocks
                .get(i as usize)
                .map(|b| &self.shapes[b.shape as usize])
        };
        match &self.transport {
            Some(TransportOps::Lightfield(entries)) => {
                for e in entries {
                    let (Some(target), Some(source)) =
                        (block_shape(e.target_block), block_shape(e.source_block))
                    else {
                        return bad("transport: entry names a missing block".into());
                    };
                    let Some(opening) = target.openings.iter().find(|o| o.face == e.target_face)
                    else {
                        return bad("transport: entry names an opening the shape lacks".into());
                    };
                    if e.matrix.rows != opening.u_r.cols || e.matrix.cols != source.u_b.cols {
                        return bad("transport: propagation matrix has the wrong size".into());
                    }
                }
            }
            Some(TransportOps::Traced(entries)) => {
                for e in entries {
                    let (Some(target), Some(source)) =
                        (block_shape(e.target_block), block_shape(e.source_block))
                    else {
                        return bad("transport: entry names a missing block".into());
                    };
                    if e.matrix.rows != target.u_b.rows || e.matrix.cols != source.u_b.cols {
                        return bad("transport: traced matrix has the wrong size".into());
                    }
                }
            }
            None => {}
        }
        if let Some(f) = &self.full {
            if f.n as u64 != n_texels || f.row_start.len() as u64 != n_texels + 1 {
                return bad("full: size does not match the layout".into());
            }
            if f.row_start.first() != Some(&0)
                || f.row_start.windows(2).any(|w| w[1] < w[0])
                || *f.row_start.last().unwrap() as usize != f.cols.len()
                || f.cols.len() != f.values.len()
            {
                return bad("full: row starts are inconsistent".into());
            }
            if f.cols.iter().any(|c| *c >= f.n) || f.values.iter().any(|v| !v.is_finite()) {
                return bad("full: column index or value out of range".into());
            }
        }
        if let Some(d) = &self.drt {
            let n_blocks = self.blocks.len() as u64;
            let n_clutter = d.clutter.len() as u64;
            for (k, c) in d.clutter.iter().enumerate() {
                if c.texel_offset as u64 + c.t_dc.cols as u64 > n_texels
                    || c.t_dc.rows > c.t_dc.cols
                {
                    return bad(format!("drt: clutter {k} texel range past the layout"));
                }
            }
            for (k, e) in d.entries.iter().enumerate() {
                let cols = match e.source {
                    DeltaSource::Block(b) if (b as u64) < n_blocks => {
                        self.shapes[self.blocks[b as usize].shape as usize].u_b.cols
                    }
                    DeltaSource::Clutter(c) if (c as u64) < n_clutter => {
                        d.clutter[c as usize].t_dc.rows
                    }
                    _ => return bad(format!("drt: entry {k} names a missing source")),
                };
                if e.matrix.rows as usize != e.rows.len() || e.matrix.cols != cols {
                    return bad(format!("drt: entry {k} matrix has the wrong size"));
                }
                if e.rows.iter().any(|r| *r as u64 >= n_texels)
                    || e.rows.windows(2).any(|w| w[1] <= w[0])
                {
                    return bad(format!("drt: entry {k} rows out of range or not ascending"));
                }
            }
            if d.buried.iter().any(|r| *r as u64 >= n_texels) {
                return bad("drt: buried texel out of range".into());
            }
            if let Some(g) = &d.direct_gather {
                let ok = g.row_start.len() == g.rows.len() + 1
                    && g.row_start.first() == Some(&0)
                    && g.row_start.windows(2).all(|w| w[1] >= w[0])
                    && g.row_start.last().map(|l| *l as usize) == Some(g.cols.len())
                    && g.cols.len() == g.values.len()
                    && g.rows.windows(2).all(|w| w[1] > w[0])
                    && g.rows.iter().chain(&g.cols).all(|r| (*r as u64) < n_texels)
                    && g.values.iter().all(|v| v.is_finite());
                if !ok {
                    return bad("drt: direct gather is inconsistent".into());
                }
            }
        }
        if let Some(p) = &self.probes {
            let cells = p
                .dims
                .iter()
                .try_fold(1u64, |acc, d| acc.checked_mul(*d as u64))
                .unwrap_or(u64::MAX);
            if !(p.spacing.is_finite() && p.spacing > 0.0)
                || p.origin.iter().any(|x| !x.is_finite())
            {
                return bad("probes: bad grid origin or spacing".into());
            }
            if cells != p.slot.len() as u64 || p.n_probes as u64 > cells {
                return bad("probes: grid size does not match its slots".into());
            }
            if p.slot.iter().any(|s| *s != u32::MAX && *s >= p.n_probes) {
                return bad("probes: slot names a missing probe".into());
            }
            let n_clutter = self.drt.as_ref().map_or(0, |d| d.clutter.len()) as u64;
            let rows_max = p.n_probes as u64 * crate::sh::SH_COEFFS as u64;
            for (k, e) in p.entries.iter().enumerate() {
                let cols = match e.source {
                    DeltaSource::Block(b) if (b as u64) < self.blocks.len() as u64 => {
                        self.shapes[self.blocks[b as usize].shape as usize].u_b.cols
                    }
                    DeltaSource::Clutter(c) if (c as u64) < n_clutter => {
                        self.drt.as_ref().unwrap().clutter[c as usize].t_dc.rows
                    }
                    _ => return bad(format!("probes: entry {k} names a missing source")),
                };
                if e.matrix.rows as usize != e.rows.len() || e.matrix.cols != cols {
                    return bad(format!("probes: entry {k} matrix has the wrong size"));
                }
                if e.rows.iter().any(|r| *r as u64 >= rows_max)
                    || e.rows.windows(2).any(|w| w[1] <= w[0])
                {
                    return bad(format!(
                        "probes: entry {k} rows out of range or not ascending"
                    ));
                }
            }
        }
        if let Some(grids) = &self.dnrt {
            for (k, g) in grids.iter().enumerate() {
                g.validate()
                    .map_err(|e| BundleError::Invalid(e.to_string()))?;
                if grids[..k].iter().any(|o| o.object == g.object) {
                    return bad(format!("dnrt: two grids for object \"{}\"", g.object));
                }
            }
        }
        Ok(())
    }
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
    let direct_gather = match r.u8()? {
        0 => None,
        1 => Some(TexelGather {
            rows: r.u32s()?,
            row_start: r.u32s()?,
            cols: r.u32s()?,
            values: r.f32s()?,
        }),
        k => {
            return Err(BundleError::Invalid(format!(
                "drt: unknown gather flag {k}"
            )))
        }
    };
    Ok(DrtOps {
        clutter,
        entries,
        buried,
        direct_gather,
    })
}

fn write_entries(w: &mut Writer, entries: &[DeltaEntry]) {
    w.u32(entries.len() as u32);
    for e in entries {
        w.u32s(&e.rows);
        match e.source {
            DeltaSource::Block(b) => {
                w.u8(0);
                w.u32(b);
            }
            DeltaSource::Clutter(c) => {
                w.u8(1);
                w.u32(c);
            }
        }
        e.matrix.write(w);
    }
}

fn read_entries(r: &mut Reader) -> Result<Vec<DeltaEntry>, BundleError> {
    let n_entries = r.u32()? as usize;
    let mut entries = Vec::with_capacity(n_entries.min(r.remaining() / 24));
    for _ in 0..n_entries {
        let rows = r.u32s()?;
        let source = match r.u8()? {
            0 => DeltaSource::Block(r.u32()?),
            1 => DeltaSource::Clutter(r.u32()?),
            k => {
                return Err(BundleError::Invalid(format!(
                    "delta entry: unknown source kind {k}"
                )))
            }
        };
        entries.push(DeltaEntry {
            rows,
            source,
            matrix: Matrix::read(r, "delta entry")?,
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
