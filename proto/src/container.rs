//! The bundle container: header, sections (each compressed and checksummed), table of contents.
//!
//! ```text
//! file    := header section* end footer
//! header  := "LFBUNDLE" major:u16 minor:u16
//! section := kind:u32 flags:u32 stored_len:u64 raw_len:u64 checksum:u64 payload[stored_len]
//! end     := a section of kind 0 whose payload is the table of contents:
//!            count:u32 then per section (kind:u32 header_offset:u64 stored_len:u64 raw_len:u64)
//! footer  := end_header_offset:u64 "LFBUNDLE"
//! ```
//! `flags` bit 0: the payload is zstd-compressed (`raw_len` bytes once decompressed; one frame, or
//! several concatenated, as a stream decoder reads them: [`SECTION_FRAME_BYTES`]); other bits
//! are reserved and refused in sections this reader knows. `checksum` is FNV-1a over the stored
//! (possibly compressed) payload, so corruption is caught before decompression.
//!
//! Sections are self-delimiting, so a reader can consume a bundle as it streams and use every
//! complete section before the rest arrives ([`read_sections`] with `allow_truncated`); the
//! table of contents at the end lets a random-access reader find sections without scanning.
//!
//! Invariant: reading never panics and never allocates more than the limit on a section's
//! decompressed size ([`MAX_SECTION_BYTES`]) or the bytes actually present.

use std::io::Read;

use crate::wire::{checksum, Reader, WireError, Writer};
use crate::work_queue::{cores, map_in_order};

pub const MAGIC: &[u8; 8] = b"LFBUNDLE";
/// Kind of the closing table-of-contents section.
pub const END: u32 = 0;
const FLAG_ZSTD: u32 = 1;
const HEADER_BYTES: u64 = 4 + 4 + 8 + 8 + 8;
/// Largest decompressed section a reader accepts (1 GiB).
pub const MAX_SECTION_BYTES: u64 = 1 << 30;

/// Why bytes are not a well-formed container.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ContainerError {
    #[error("not a lightfarm bundle (bad magic)")]
    Magic,
    #[error("bundle major version {found} is not the version this reader knows ({known}); update the client")]
    Version { found: u16, known: u16 },
    #[error("section {kind}: checksum mismatch (corrupt bundle)")]
    Checksum { kind: u32 },
    #[error("section {kind}: {reason}")]
    Section { kind: u32, reason: String },
    #[error("bundle ends before its table of contents (truncated)")]
    Truncated,
    #[error("bundle: {0}")]
    Wire(#[from] WireError),
}

/// One section as stored: kind, whether zstd-compressed, raw and stored sizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SectionInfo {
    pub kind: u32,
    pub compressed: bool,
    pub raw_len: u64,
    pub stored_len: u64,
}

/// Sections up to this many raw bytes are compressed at level [`SMALL_SECTION_ZSTD_LEVEL`] or
/// above: that costs a fifth of a second on a 1 MB bundle (whose download it shrinks by about 5%:
/// the maze at T=8, 595 → 567 KB), while a large section keeps the caller's level, whose time
/// grows with its size.
pub const SMALL_SECTION_BYTES: usize = 1 << 20;
/// See [`SMALL_SECTION_BYTES`].
pub const SMALL_SECTION_ZSTD_LEVEL: i32 = 19;

/// The zstd level a section of `raw_len` bytes is written at, for a container written at
/// `zstd_level` (0: stored raw).
pub fn section_zstd_level(zstd_level: i32, raw_len: usize) -> i32 {
    if zstd_level > 0 && raw_len <= SMALL_SECTION_BYTES {
        zstd_level.max(SMALL_SECTION_ZSTD_LEVEL)
    } else {
        zstd_level
    }
}

/// A section larger than [`SMALL_SECTION_BYTES`] is compressed as consecutive zstd frames of
/// this many raw bytes each (the last shorter), compressed side by side and concatenated: a
/// stream any zstd decoder reads as one payload. Each frame is single-threaded zstd of its own
/// bytes, so the payload does not depend on the number of threads. Measured on the maze's
/// 15.6 MB DRT section at level 9: 3,555,398 B in 0.36 s as one frame in zstd's multi-threaded
/// mode (which cut it into a single job), 3,530,094 B in 0.25 s of one core's time as four
/// frames of 4 MiB.
pub const SECTION_FRAME_BYTES: usize = 4 << 20;

/// A section's stored payload at zstd `level`: the compressed bytes when they are smaller than
/// `raw`, None to store it raw (also at level 0). A pure function of its arguments. A section
/// larger than [`SMALL_SECTION_BYTES`] is cut into frames of [`SECTION_FRAME_BYTES`] compressed
/// on every core.
pub fn compress_section(raw: &[u8], level: i32) -> Option<Vec<u8>> {
    if level == 0 {
        return None;
    }
    let compressed = if raw.len() > SMALL_SECTION_BYTES {
        compress_frames(raw, level, SECTION_FRAME_BYTES)
    } else {
        zstd::bulk::compress(raw, level)
    };
    compressed.ok().filter(|c| c.len() < raw.len())
}

/// `raw` as consecutive zstd frames of `frame` raw bytes each, compressed at `level` on up to
/// as many threads as there are cores (the bytes do not depend on how many).
fn compress_frames(raw: &[u8], level: i32, frame: usize) -> std::io::Result<Vec<u8>> {
    let pieces: Vec<&[u8]> = raw.chunks(frame).collect();
    let frames = map_in_order(&pieces, cores(), |_, piece| {
        // Shrunk to its length: a frame is allocated at its raw size's bound, and a large
        // section's frames are all held until they are joined.
        zstd::bulk::compress(piece, level).map(|mut f| {
            f.shrink_to_fit();
            f
        })
    });
    let mut joined = Vec::new();
    for f in frames {
        joined.extend_from_slice(&f?);
    }
    Ok(joined)
}

/// Writes a container. `zstd_level` 0 stores payloads raw; small sections are compressed harder
/// ([`section_zstd_level`]).
pub fn write_container(
    major: u16,
    minor: u16,
    sections: &[(u32, Vec<u8>)],
    zstd_level: i32,
) -> (Vec<u8>, Vec<SectionInfo>) {
    write_container_with(major, minor, sections, zstd_level, &|_, raw, level| {
        compress_section(raw, level)
    })
}

/// How [`write_container_with`] gets a section's stored payload: `(kind, raw, level)` →
/// what [`compress_section`]`(raw, level)` gives.
pub type CompressSection<'a> = dyn Fn(u32, &[u8], i32) -> Option<Vec<u8>> + Sync + 'a;

/// [`write_container`] taking each section's stored payload from `compress(kind, raw, level)`,
/// which must give what [`compress_section`] gives for `raw` at `level` or at a level it
/// chooses for `kind` (the bundle writer raises some kinds'), or what it gave in an earlier
/// write of the same bytes: a pure function of its arguments. Sections are compressed side by
/// side, one thread each.
pub fn write_container_with(
    major: u16,
    minor: u16,
    sections: &[(u32, Vec<u8>)],
    zstd_level: i32,
    compress: &CompressSection<'_>,
) -> (Vec<u8>, Vec<SectionInfo>) {
    let mut w = Writer::new();
    w.bytes.extend_from_slice(MAGIC);
    w.bytes.extend_from_slice(&major.to_le_bytes());
    w.bytes.extend_from_slice(&minor.to_le_bytes());
    let mut toc = Vec::with_capacity(sections.len());
    let mut infos = Vec::with_capacity(sections.len());
    let compressed: Vec<Option<Vec<u8>>> = std::thread::scope(|scope| {
        let handles: Vec<_> = sections
            .iter()
            .map(|(kind, raw)| {
                scope.spawn(|| compress(*kind, raw, section_zstd_level(zstd_level, raw.len())))
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("a section compressor panicked"))
            .collect()
    });
    for ((kind, raw), compressed) in sections.iter().zip(compressed) {
        let offset = w.bytes.len() as u64;
        let (flags, stored): (u32, &[u8]) = match &compressed {
            Some(c) => (FLAG_ZSTD, c),
            None => (0, raw),
        };
        write_section(&mut w, *kind, flags, stored, raw.len() as u64);
        toc.push((*kind, offset, stored.len() as u64, raw.len() as u64));
        infos.push(SectionInfo {
            kind: *kind,
            compressed: flags & FLAG_ZSTD != 0,
            raw_len: raw.len() as u64,
            stored_len: stored.len() as u64,
        });
    }
    let end_offset = w.bytes.len() as u64;
    let mut t = Writer::new();
    t.u32(toc.len() as u32);
    for (kind, offset, stored, raw) in &toc {
        t.u32(*kind);
        t.u64(*offset);
        t.u64(*stored);
        t.u64(*raw);
    }
    write_section(&mut w, END, 0, &t.bytes, t.bytes.len() as u64);
    w.u64(end_offset);
    w.bytes.extend_from_slice(MAGIC);
    (w.bytes, infos)
}

/// Where the closing table of contents starts in a complete container (from its footer): the
/// bytes before it are the header and every section, i.e. what a streaming reader can use.
pub fn sections_end(bytes: &[u8]) -> Option<usize> {
    let n = bytes.len();
    if n < 16 + 8 || &bytes[n - 8..] != MAGIC {
        return None;
    }
    let end = u64::from_le_bytes(bytes[n - 16..n - 8].try_into().ok()?);
    (end >= 12 && end <= (n - 16) as u64).then_some(end as usize)
}

fn write_section(w: &mut Writer, kind: u32, flags: u32, stored: &[u8], raw_len: u64) {
    w.u32(kind);
    w.u32(flags);
    w.u64(stored.len() as u64);
    w.u64(raw_len);
    w.u64(checksum(stored));
    w.bytes.extend_from_slice(stored);
}

/// The sections read from a container, in file order, decompressed.
#[derive(Debug, Default)]
pub struct Sections {
    pub minor: u16,
    pub sections: Vec<(u32, Vec<u8>)>,
    /// Whether the closing table of contents (and footer) was present and consistent.
    pub complete: bool,
}

/// Reads a container. `known` says which section kinds to decompress (others are skipped
/// unread, as a newer minor version's sections). With `allow_truncated`, a bundle cut anywhere
/// after its header gives the complete sections before the cut and `complete == false`;
/// without it, anything short of a full, consistent container is an error.
pub fn read_sections(
    bytes: &[u8],
    majors: std::ops::RangeInclusive<u16>,
    known: impl Fn(u32) -> bool,
    allow_truncated: bool,
) -> Result<Sections, ContainerError> {
    let mut r = Reader::new(bytes);
    if r.take(8).map_err(|_| ContainerError::Magic)? != MAGIC {
        return Err(ContainerError::Magic);
    }
    let found = u16::from_le_bytes(r.take(2)?.try_into().unwrap());
    let minor = u16::from_le_bytes(r.take(2)?.try_into().unwrap());
    if !majors.contains(&found) {
        return Err(ContainerError::Version {
            found,
            known: *majors.end(),
        });
    }
    let mut out = Sections {
        minor,
        ..Sections::default()
    };
    let mut offsets: Vec<(u32, u64, u64, u64)> = Vec::new();
    loop {
        let header_offset = r.position() as u64;
        if (r.remaining() as u64) < HEADER_BYTES {
            return truncated(out, allow_truncated);
        }
        let kind = r.u32()?;
        let flags = r.u32()?;
        let stored_len = r.u64()?;
        let raw_len = r.u64()?;
        let sum = r.u64()?;
        if stored_len > r.remaining() as u64 {
            return truncated(out, allow_truncated);
        }
        let stored = r.take(stored_len as usize)?;
        if kind == END {
            if r.remaining() < 16 {
                return truncated(out, allow_truncated);
            }
            if flags != 0 || raw_len != stored_len {
                return Err(ContainerError::Section {
                    kind,
                    reason: "table of contents has flags or a raw length".into(),
                });
            }
            check_toc(stored, &offsets, sum, &mut r, header_offset)?;
            out.complete = true;
            return Ok(out);
        }
        offsets.push((kind, header_offset, stored_len, raw_len));
        if !known(kind) {
            continue;
        }
        if checksum(stored) != sum {
            return Err(ContainerError::Checksum { kind });
        }
        let bad = |reason: String| ContainerError::Section { kind, reason };
        if flags & !FLAG_ZSTD != 0 {
            return Err(bad(format!("unknown flags {flags:#x}")));
        }
        if raw_len > MAX_SECTION_BYTES {
            return Err(bad(format!(
                "decompressed size {raw_len} exceeds the {MAX_SECTION_BYTES}-byte limit"
            )));
        }
        let payload = if flags & FLAG_ZSTD != 0 {
            decompress(stored, raw_len).map_err(bad)?
        } else if raw_len != stored_len {
            return Err(bad(format!(
                "raw length {raw_len} differs from stored length {stored_len}"
            )));
        } else {
            stored.to_vec()
        };
        out.sections.push((kind, payload));
    }
}

fn truncated(out: Sections, allow: bool) -> Result<Sections, ContainerError> {
    if allow {
        Ok(out)
    } else {
        Err(ContainerError::Truncated)
    }
}

/// Decompresses exactly `raw_len` bytes; allocation grows only with data actually produced.
fn decompress(stored: &[u8], raw_len: u64) -> Result<Vec<u8>, String> {
    let decoder = zstd::stream::read::Decoder::new(stored).map_err(|e| format!("zstd: {e}"))?;
    let mut payload = Vec::new();
    decoder
        .take(raw_len + 1)
        .read_to_end(&mut payload)
        .map_err(|e| format!("zstd: {e}"))?;
    if payload.len() as u64 != raw_len {
        return Err(format!(
            "decompresses to {} bytes, header says {raw_len}",
            payload.len()
        ));
    }
    Ok(payload)
}

/// Checks the table of contents against the sections read, and the footer after it.
fn check_toc(
    toc: &[u8],
    seen: &[(u32, u64, u64, u64)],
    sum: u64,
    r: &mut Reader,
    end_offset: u64,
) -> Result<(), ContainerError> {
    let bad = |reason: &str| ContainerError::Section {
        kind: END,
        reason: reason.into(),
    };
    if checksum(toc) != sum {
        return Err(ContainerError::Checksum { kind: END });
    }
    let mut t = Reader::new(toc);
    let n = t.u32()? as usize;
    if n != seen.len() {
        return Err(bad(
            "table of contents lists a different number of sections",
        ));
    }
    for expected in seen {
        let entry = (t.u32()?, t.u64()?, t.u64()?, t.u64()?);
        if entry != *expected {
            return Err(bad("table of contents does not match the sections"));
        }
    }
    if r.remaining() != 16 || r.u64()? != end_offset || r.take(8)? != MAGIC {
        return Err(bad("footer missing or inconsistent"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn sample() -> Vec<(u32, Vec<u8>)> {
        vec![
            (1, b"layout".repeat(100)),
            (2, (0..=255u8).collect()),
            (99, vec![7; 50]),
        ]
    }

    /// A large section is stored as frames of [`SECTION_FRAME_BYTES`]: each is the
    /// single-threaded frame of its own bytes (so a bake is the same bytes on any machine), and
    /// the concatenation reads back as the section, through the container and through a plain
    /// zstd stream decoder (what an older reader uses).
    #[test]
    fn large_sections_are_frames_that_read_back_as_one_payload() {
        // 9 MB of half-compressible bytes: three frames, the last one short.
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let raw: Vec<u8> = (0..9 << 20)
            .map(|i| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                if i % 3 == 0 {
                    (i / 1024) as u8
                } else {
                    (x >> 59) as u8
                }
            })
            .collect();
        assert!(raw.len() > SMALL_SECTION_BYTES);
        let stored = compress_section(&raw, 9).unwrap();
        let frames: Vec<u8> = raw
            .chunks(SECTION_FRAME_BYTES)
            .flat_map(|c| zstd::bulk::compress(c, 9).unwrap())
            .collect();
        assert_eq!(raw.chunks(SECTION_FRAME_BYTES).count(), 3);
        assert_eq!(stored, frames);
        assert!(stored.len() < raw.len() * 3 / 4);
        assert_eq!(zstd::stream::decode_all(stored.as_slice()).unwrap(), raw);
        assert_eq!(decompress(&stored, raw.len() as u64).unwrap(), raw);
        let (bytes, infos) = write_container(1, 0, &[(4, raw.clone())], 9);
        assert!(infos[0].compressed);
        let s = read_sections(&bytes, 1..=1, |_| true, false).unwrap();
        assert_eq!(s.sections, vec![(4, raw)]);
    }

    #[test]
    fn round_trip_compresses_what_shrinks_and_skips_unknown_kinds() {
        let (bytes, infos) = write_container(1, 0, &sample(), 3);
        assert!(infos[0].compressed && infos[0].stored_len < infos[0].raw_len);
        assert!(!infos[1].compressed, "incompressible payload stored raw");
        let s = read_sections(&bytes, 1..=1, |k| k != 99, false).unwrap();
        assert!(s.complete);
        assert_eq!(s.sections, sample()[..2].to_vec());
    }

    #[test]
    fn every_prefix_reads_as_its_complete_sections() {
        let (bytes, _) = write_container(1, 0, &sample(), 3);
        let mut last = 0;
        for cut in 12..bytes.len() {
            let s = read_sections(&bytes[..cut], 1..=1, |_| true, true).unwrap();
            assert!(!s.complete);
            assert!(s.sections.len() >= last);
            last = s.sections.len();
            assert!(read_sections(&bytes[..cut], 1..=1, |_| true, false).is_err());
        }
        assert_eq!(last, 3);
    }

    #[test]
    fn other_major_and_flipped_bytes_are_errors() {
        let (bytes, _) = write_container(1, 0, &sample(), 3);
        assert_eq!(
            read_sections(&bytes, 2..=2, |_| true, false).unwrap_err(),
            ContainerError::Version { found: 1, known: 2 }
        );
        for k in 12..bytes.len() {
            let mut b = bytes.clone();
            b[k] ^= 0x40;
            assert!(
                read_sections(&b, 1..=1, |_| true, false).is_err(),
                "flip at {k} went unnoticed"
            );
        }
    }

    #[test]
    fn a_lying_raw_length_is_refused_without_allocating_it() {
        let (mut bytes, _) = write_container(1, 0, &[(1, vec![0u8; 4096])], 3);
        // raw_len sits at offset 12 + 4 + 4 + 8.
        bytes[24..32].copy_from_slice(&(1u64 << 40).to_le_bytes());
        let err = read_sections(&bytes, 1..=1, |_| true, false).unwrap_err();
        assert!(
            matches!(err, ContainerError::Section { kind: 1, .. }),
            "{err}"
        );
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]
        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
            let mut b = MAGIC.to_vec();
            b.extend_from_slice(&[1, 0, 0, 0]);
            b.extend_from_slice(&bytes);
            let _ = read_sections(&b, 1..=1, |_| true, true);
            let _ = read_sections(&bytes, 1..=1, |_| true, false);
        }
    }
}
