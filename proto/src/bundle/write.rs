//! Writing a bundle: [`Bundle::encode`] and [`Bundle::encode_with`] (every section's payload in
//! file order, framed by [`crate::container::write_container`]) and [`Bundle::raw_sections`]
//! (the payloads alone). Shapes and transport sections larger than the container's small
//! sections are compressed at zstd level 16 at least (`STABLE_SECTION_ZSTD_LEVEL`).
//!
//! Invariant: the header always carries the writer's version ([`BUNDLE_MAJOR`].[`BUNDLE_MINOR`]),
//! whatever sections a bundle has, so a streamed prefix and the whole bundle share their header
//! bytes. Only current section kinds are written: blocks as kind 14, DRT as kind 23 with its
//! exact gather in form 3 (form 2 when form 3 cannot hold it). The older kinds 3, 6 and 11 are
//! still read ([`super::read`], [`super::legacy_1x`]) and never written; the DRT kinds 13 and
//! 20–22 only for tests ([`Bundle::raw_sections_as_2_6`], [`Bundle::raw_sections_as_2_7`]).

use crate::container::{compress_section, write_container_with};
use crate::dnrt_grid::DnrtCodec;
use crate::wire::Writer;

use super::delta_entries::{write_entries, FlooredLeft};
use super::gather_model::GatherFrame;
use super::index_lists::{write_index_list, IndexLists};
use super::matrix_codec::{EncodingMemo, MatrixEncoder};
use super::sections::{section, section_name};
use super::{dynamic_shapes, gather_encoding, sh_responses, symmetric_blocks};
use super::{
    Bundle, CompactEntry, EncodeOptions, EncodeReport, GatherTiles, Layout, TransportOps,
    BUNDLE_MAJOR, BUNDLE_MINOR,
};

/// Share of the transport codec budget a source basis of transport kind 3 is coded within, and
/// the share its receivers' `Z'` are: with both, the maze's all-bounce DRT error is the one of
/// kind 2 at the full budget (0.0398 over four light sets), where the full budget for both gave
/// 0.0403. Bases at a quarter gave the same error in f16 (an orthonormal row of ~120 values
/// needs ~0.75% on an 8-bit grid), at half they are 8-bit: grid1000 transport 23.2 → 21.5 MB.
const BASIS_BUDGET: f64 = 0.5;
const FACTORED_Z_BUDGET: f64 = 0.75;

/// What a DRT section is written as: this writer's kind 23, or what an older writer wrote (for
/// the tests of older readers' and this reader's compatibility).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum DrtForm {
    /// Kind 13, 20 or 21, index lists plain.
    AsOf2_6,
    /// Kind 22: index lists packed, the gather in form 2.
    AsOf2_7,
    /// Kind 23: index lists packed, the gather in form 3 where it can be.
    Current,
}

/// The least zstd level of a shapes or transport section larger than the container's small
/// sections ([`crate::container::SMALL_SECTION_BYTES`], which are compressed at 19 already).
/// A clutter edit leaves both sections unchanged, so a rebake takes them from the encoding
/// memo and only a cold bake pays for the level. Level 16 is zstd's first `btopt` level:
/// through [`compress_section`] on one core, grid1000's shapes section (9.4 MB raw) took
/// 6,041,248 B at level 9 (0.32 s), 5,885,985 B at 16 (3.90 s) and 6,031,953 B at 19
/// (5.13 s); its transport 6,483,034, 6,401,589 and 6,427,031 B (0.28, 2.54, 3.86 s). The
/// DRT section, which every clutter edit changes, keeps the caller's level.
const STABLE_SECTION_ZSTD_LEVEL: i32 = 16;

/// The zstd level section `kind` of `raw_len` bytes is written at, for a bundle written at
/// `level` (what [`crate::container::section_zstd_level`] gave; 0: stored raw).
fn bundle_section_zstd_level(kind: u32, raw_len: usize, level: i32) -> i32 {
    let stable = matches!(
        kind,
        section::SHAPES | section::TRANSPORT | section::TRANSPORT_SOURCE_BASES
    );
    if stable && level > 0 && raw_len > crate::container::SMALL_SECTION_BYTES {
        level.max(STABLE_SECTION_ZSTD_LEVEL)
    } else {
        level
    }
}

/// Compact transport entries (kinds 2 and 3): count, then per entry target, sources, y, z.
fn write_compact_entries<'a>(
    w: &mut Writer,
    entries: &'a [CompactEntry],
    enc: &mut MatrixEncoder<'a>,
) {
    w.u32(entries.len() as u32);
    for e in entries {
        w.u32(e.target_block);
        w.u32s(&e.sources);
        e.y.write(w, enc);
        e.z.write(w, enc);
    }
}

fn write_vec3s(w: &mut Writer, v: &[[f32; 3]]) {
    let flat: Vec<f32> = v.iter().flatten().copied().collect();
    w.f32s(&flat);
}

impl Layout {
    pub(super) fn write(&self, w: &mut Writer) {
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
}

impl Bundle {
    /// Encodes the bundle losslessly ([`EncodeOptions::default`]).
    pub fn encode(&self) -> Vec<u8> {
        self.encode_with(&EncodeOptions::default()).0
    }

    /// Encodes the bundle with the given codecs and compression. The operator matrices are
    /// encoded on every core (a first pass lists them; each matrix's bytes are its own), then
    /// written in file order: the same bytes and report as one thread.
    pub fn encode_with(&self, options: &EncodeOptions) -> (Vec<u8>, EncodeReport) {
        let threads = crate::work_queue::cores();
        self.encode_on(options, threads)
    }

    /// [`Bundle::encode_with`] on `threads` threads; one thread encodes each matrix as it
    /// writes it (no listing pass). Every thread count gives the same bytes and report.
    pub fn encode_on(&self, options: &EncodeOptions, threads: usize) -> (Vec<u8>, EncodeReport) {
        self.encode_memo(options, threads, None)
    }

    /// [`Bundle::encode_on`] taking each matrix's encoding from `memo` where it has one, and
    /// handing it every matrix's encoding in file order ([`EncodingMemo`]): the same bytes and
    /// report, with the unchanged matrices of a rebake not encoded again.
    pub fn encode_memo(
        &self,
        options: &EncodeOptions,
        threads: usize,
        memo: Option<&dyn EncodingMemo>,
    ) -> (Vec<u8>, EncodeReport) {
        let mut enc = if threads > 1 || memo.is_some() {
            let mut listing = MatrixEncoder::listing(options);
            self.encode_sections(&mut listing);
            listing.encode_listed(options, threads, memo)
        } else {
            MatrixEncoder::new(options)
        };
        let sections = self.encode_sections(&mut enc);
        // Always the writer's minor version, whatever sections this bundle has: a streamed
        // prefix (MRT sections only) and the whole bundle must share their header bytes.
        let minor = BUNDLE_MINOR;
        let compress = |kind: u32, raw: &[u8], level: i32| {
            let level = bundle_section_zstd_level(kind, raw.len(), level);
            let fresh = || compress_section(raw, level);
            match memo {
                Some(memo) => memo.section(kind, raw, level, &fresh),
                None => fresh(),
            }
        };
        let (bytes, infos) = write_container_with(
            BUNDLE_MAJOR,
            minor,
            &sections,
            options.zstd_level,
            &compress,
        );
        let mut report = enc.report;
        report.sections = infos
            .into_iter()
            .map(|i| (section_name(i.kind), i))
            .collect();
        report.total_bytes = bytes.len() as u64;
        (bytes, report)
    }

    /// The uncompressed f32 payload of every section, in file order (what
    /// [`crate::container::write_container`] frames; for tools and tests that edit sections).
    pub fn raw_sections(&self) -> Vec<(u32, Vec<u8>)> {
        // The default options store every matrix as f32.
        let mut enc = MatrixEncoder::new(&EncodeOptions::default());
        self.encode_sections(&mut enc)
    }

    /// [`Bundle::raw_sections`] with the DRT section as a 2.6 writer wrote it: kind 13, 20 or
    /// 21, its index lists as `u32s`. For tests of what older writers wrote, which this reader
    /// still reads.
    pub fn raw_sections_as_2_6(&self) -> Vec<(u32, Vec<u8>)> {
        let mut enc = MatrixEncoder::new(&EncodeOptions::default());
        self.encode_sections_as(&mut enc, DrtForm::AsOf2_6)
    }

    /// [`Bundle::raw_sections`] with the DRT section as a 2.7 writer wrote it: kind 22, its
    /// gather in form 2. For tests of what older writers wrote, which this reader still reads.
    pub fn raw_sections_as_2_7(&self) -> Vec<(u32, Vec<u8>)> {
        let mut enc = MatrixEncoder::new(&EncodeOptions::default());
        self.encode_sections_as(&mut enc, DrtForm::AsOf2_7)
    }

    fn encode_sections<'a>(&'a self, enc: &mut MatrixEncoder<'a>) -> Vec<(u32, Vec<u8>)> {
        self.encode_sections_as(enc, DrtForm::Current)
    }

    /// Every section's payload, the DRT section in `form`.
    fn encode_sections_as<'a>(
        &'a self,
        enc: &mut MatrixEncoder<'a>,
        form: DrtForm,
    ) -> Vec<(u32, Vec<u8>)> {
        let lists = match form {
            DrtForm::AsOf2_6 => IndexLists::Plain,
            DrtForm::AsOf2_7 | DrtForm::Current => IndexLists::Packed,
        };
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
        if let Some(rooms) = &self.rooms {
            let mut w = Writer::new();
            rooms.write(&mut w);
            sections.push((section::ROOMS, w.bytes));
        }

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
                    write_compact_entries(&mut w, entries, enc);
                }
                TransportOps::Factored(f) => {
                    w.u8(3);
                    w.u32(f.bases.len() as u32);
                    // The factoring spends some of the error the codec would; its matrices get
                    // a tighter share of the transport's budget, a basis the tightest: it
                    // carries its source's light to every receiver, so its error repeats in each.
                    enc.with_budget_scaled(BASIS_BUDGET, |enc| {
                        for b in &f.bases {
                            w.u32(b.source_block);
                            b.q.write(&mut w, enc);
                        }
                    });
                    enc.with_budget_scaled(FACTORED_Z_BUDGET, |enc| {
                        write_compact_entries(&mut w, &f.entries, enc)
                    });
                }
            });
            let kind = match t {
                TransportOps::Factored(_) => section::TRANSPORT_SOURCE_BASES,
                _ => section::TRANSPORT,
            };
            sections.push((kind, w.bytes));
        }
        if let Some(d) = &self.drt {
            let mut w = Writer::new();
            w.u32(d.clutter.len() as u32);
            for c in &d.clutter {
                w.str(&c.id);
                w.u32(c.texel_offset);
                c.t_dc.write(&mut w, enc);
            }
            // A delta entry's matrix (dense, or `U_k Σ_k`) takes one floor on its lines' steps:
            // measured against the reference, the error stayed put and the section shrank by
            // 11-13% (docs/bundle-format.md, Codecs). The clutter's `T_d→c`, the entries' mixes,
            // the shapes and the transport keep each line's own grid: there a floor cost error.
            write_entries(&mut w, &d.entries, enc, FlooredLeft::Yes, lists);
            write_index_list(&mut w, &d.buried, lists);
            let modelled = (form == DrtForm::Current).then(|| GatherFrame::of(&self.layout));
            // A listing pass drops these bytes, and the gather holds no matrix: skipped there.
            let wide = !enc.is_listing()
                && gather_encoding::write_gather(&mut w, d.direct_gather.as_ref(), lists, modelled);
            write_index_list(&mut w, &d.replaced, lists);
            let no_tiles = GatherTiles::default();
            let tiles = d.direct_gather.as_ref().map_or(&no_tiles, |g| &g.tiles);
            // Kind 23 (what this writer writes): kind 21's layout, the tiles always there, every
            // texel index list packed (`index_lists`) and the gather modelled where it can be
            // (`gather_model`). As of 2.7, kind 22 (no modelled gather); as of 2.6, the kind a
            // 2.6 writer chose.
            let kind = match form {
                DrtForm::Current => section::DRT_MODELLED_GATHER,
                DrtForm::AsOf2_7 => section::DRT_PACKED_LISTS,
                DrtForm::AsOf2_6 if !tiles.is_empty() => section::DRT_TILED_GATHER,
                DrtForm::AsOf2_6 if wide => section::DRT_WIDE_COUNTS,
                DrtForm::AsOf2_6 => section::DRT_REPLACING,
            };
            if !matches!(kind, section::DRT_REPLACING | section::DRT_WIDE_COUNTS) {
                tiles.write(&mut w, lists);
            }
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
            // Probe deltas keep each line's own grid: a floor was not measured on them.
            write_entries(&mut w, &p.entries, enc, FlooredLeft::No, IndexLists::Plain);
            // A low-rank entry needs kind 17, which a reader that cannot apply it skips.
            let kind = if p.entries.iter().any(|e| e.mix.is_some()) {
                section::PROBES_LOW_RANK
            } else {
                section::PROBES
            };
            sections.push((kind, w.bytes));
        }
        if let Some(grids) = &self.dnrt {
            let mut w = Writer::new();
            w.u32(grids.len() as u32);
            // 8-bit grids in their planar, differenced form (codec tag 3), which needs kind 18:
            // a reader that does not know the tag skips the section.
            let planar = grids.iter().any(|g| g.data.codec() == DnrtCodec::U8);
            for g in grids {
                if planar {
                    g.write_planar(&mut w);
                } else {
                    g.write(&mut w);
                }
            }
            let kind = if planar {
                section::DNRT_PLANAR
            } else {
                section::DNRT
            };
            sections.push((kind, w.bytes));
        }
        if !self.dynamic_shapes.is_empty() {
            let mut w = Writer::new();
            dynamic_shapes::write(&mut w, &self.dynamic_shapes);
            sections.push((section::DYNAMIC_SHAPES, w.bytes));
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
}
