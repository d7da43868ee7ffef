//! How the DRT section stores the exact gather ([`TexelGather`]), the largest sparse operator
//! of a bundle.
//!
//! Flag byte, then:
//! - `0`: no gather;
//! - `1` (1.x, still read, by `legacy_1x`): CSR as it is in memory, `rows:u32s row_start:u32s
//!   cols:u32s values:f32s`;
//! - `2` (2.0; what the writer uses outside section 23, and in it for a gather form 3 cannot
//!   hold): `rows:u32s row_start:u32s` (in sections 22 and 23 both packed,
//!   `index_lists`), then the columns as `len:u64` bytes of LEB128 varints, per row the first
//!   column and after it each column minus the previous one minus 1 (the writer sorts a row by
//!   column and merges repeats, so columns strictly ascend within a row), then `weights:u8`:
//!   `0` and `values:f32s`, or `1` and `unit:f32 counts:u32s-length-prefixed bytes` with
//!   value = unit · count, or (format 2.5, sections 20–23 only) `2` and `unit:f32 n:u64
//!   counts:u8×n len:u64` bytes of LEB128 varints, one per count byte of 255 in order, each the
//!   count minus 255. A gather weight is a hit fraction `hits / rays`, so a unit form is exact
//!   for every bake: the writer uses `1` when every value is `unit · count` in f32 with
//!   count ≤ 255, else `2` when it is with any count up to 2²⁴ (a texel close to a wall sends
//!   hundreds of its rays to one texel there: counts reach 819 of 1,024 on a generated
//!   80-block level), else `0`;
//! - `3` (2.8, section 23 only, what the writer uses there): each row's columns and counts
//!   range-coded under contexts from its neighbouring rows ([`gather_model`]).
//!
//! Gaps between the texels a row's rays hit are small (hits cluster on the faces they see), so
//! most columns take one byte before compression instead of four; on the maze at T=8 the
//! gather's stored bytes fall from about 92 KB to 60 KB. Escaped counts take the weights of a
//! gather with a count over 255 from 4 bytes to about 1 before compression, and after zstd at
//! the bundle's level from 876,742 to 584,847 B on the maze at T=16 (2,534,241 entries, counts
//! up to 424) and from 373,965 to 249,556 B on the 80-block level (756,011 entries).
//!
//! Invariant: reading never panics and never allocates more entries than the bytes left can
//! hold (every entry takes at least one varint byte and one weight byte); the bundle's
//! `validate` then checks indices against the layout as for form 1.

use crate::wire::{push_varint, Reader, WireError, Writer};

use super::gather_model::{self, GatherFrame, WIDEST_COUNT};
use super::index_lists::{read_index_list, write_index_list, IndexLists};
use super::{legacy_1x, BundleError, TexelGather};

impl TexelGather {
    /// Whether every row's columns strictly ascend (the form [`TexelGather::sorted`] gives).
    pub fn is_sorted(&self) -> bool {
        (0..self.rows.len()).all(|i| {
            let (s, e) = (self.row_start[i] as usize, self.row_start[i + 1] as usize);
            self.cols[s..e].windows(2).all(|w| w[0] < w[1])
        })
    }

    /// The same gather with each row's entries in ascending column order and repeated columns
    /// merged (their weights added): the form the bundle stores, so a bake that keeps its
    /// gather sorted decodes to exactly what it wrote. The tiles stay as they are.
    pub fn sorted(&self) -> TexelGather {
        let mut out = TexelGather {
            rows: self.rows.clone(),
            row_start: vec![0],
            cols: Vec::with_capacity(self.cols.len()),
            values: Vec::with_capacity(self.values.len()),
            tiles: self.tiles.clone(),
        };
        for i in 0..self.rows.len() {
            let (s, e) = (self.row_start[i] as usize, self.row_start[i + 1] as usize);
            let mut entries: Vec<(u32, f32)> = self.cols[s..e]
                .iter()
                .copied()
                .zip(self.values[s..e].iter().copied())
                .collect();
            entries.sort_by_key(|(c, _)| *c);
            let first = out.cols.len();
            for (c, v) in entries {
                if out.cols.len() > first && out.cols.last() == Some(&c) {
                    *out.values.last_mut().expect("an entry") += v;
                } else {
                    out.cols.push(c);
                    out.values.push(v);
                }
            }
            out.row_start.push(out.cols.len() as u32);
        }
        out
    }
}

/// Writes `gather` (or its absence): with `modelled` (section 23; where the layout puts the
/// gather's rows and tiles) in form 3 when it can hold the gather ([`gather_model`]), else in
/// form 2. True when form 2's weights took escaped counts (weight form 2), which only sections
/// 20–23 may hold.
pub(super) fn write_gather(
    w: &mut Writer,
    gather: Option<&TexelGather>,
    lists: IndexLists,
    modelled: Option<GatherFrame>,
) -> bool {
    let Some(g) = gather else {
        w.u8(0);
        return false;
    };
    // The bake keeps its gather sorted: re-sort (a copy) only a gather that is not.
    let sorted;
    let g = if g.is_sorted() {
        g
    } else {
        sorted = g.sorted();
        &sorted
    };
    // One unit and its counts, for form 3 and for form 2's weight forms 1 and 2.
    let counted = unit_counts(&g.values, WIDEST_COUNT as f32, |c| c as u32);
    if let Some(frame) = modelled {
        let counts = counted.as_ref().map(|(unit, c)| (*unit, c.as_slice()));
        if gather_model::write_modelled(w, g, counts, frame) {
            return false;
        }
    }
    w.u8(2);
    let TexelGather {
        rows,
        row_start,
        cols,
        values,
        ..
    } = g;
    write_index_list(w, rows, lists);
    write_index_list(w, row_start, lists);
    let mut varints = Vec::with_capacity(cols.len());
    for i in 0..rows.len() {
        let mut previous: Option<u32> = None;
        for &c in &cols[row_start[i] as usize..row_start[i + 1] as usize] {
            let gap = match previous {
                None => c,
                Some(p) => c - p - 1,
            };
            push_varint(&mut varints, gap as u64);
            previous = Some(c);
        }
    }
    w.u64(varints.len() as u64);
    w.bytes.extend_from_slice(&varints);
    // Weights that are not counts of one unit: f32 (weight form 0); every count within a
    // byte: form 1; else form 2.
    let Some((unit, counts)) = counted else {
        w.u8(0);
        w.f32s(values);
        return false;
    };
    let escaped = counts.iter().any(|&c| c > 255);
    w.u8(if escaped { 2 } else { 1 });
    w.f32(unit);
    w.u64(counts.len() as u64);
    let mut extra = Vec::new();
    for &c in &counts {
        w.u8(c.min(255) as u8);
        if escaped && c >= 255 {
            push_varint(&mut extra, (c - 255) as u64);
        }
    }
    if escaped {
        w.u64(extra.len() as u64);
        w.bytes.extend_from_slice(&extra);
    }
    escaped
}

/// Reads what [`write_gather`] wrote, or the 1.x form (`legacy_1x`); weight form 2 only when
/// `escaped_counts` (sections 20–23), form 3 only when `modelled` (section 23).
pub(super) fn read_gather(
    r: &mut Reader,
    escaped_counts: bool,
    lists: IndexLists,
    modelled: bool,
) -> Result<Option<TexelGather>, BundleError> {
    let invalid = |m: &str| BundleError::Invalid(format!("drt gather: {m}"));
    match r.u8()? {
        0 => Ok(None),
        3 if modelled => gather_model::read_modelled(r).map(Some),
        1 => legacy_1x::read_gather_csr(r).map(Some),
        2 => {
            let rows = read_index_list(r, lists)?;
            let row_start = read_index_list(r, lists)?;
            if row_start.len() != rows.len() + 1
                || row_start.first() != Some(&0)
                || row_start.windows(2).any(|w| w[1] < w[0])
            {
                return Err(invalid("row starts are not ascending from 0"));
            }
            let n = *row_start.last().expect("rows + 1 starts") as usize;
            let len = r.u64()?;
            if len > r.remaining() as u64 || n as u64 > len {
                return Err(invalid("column bytes shorter than the entries"));
            }
            let mut bytes = Reader::new(r.take(len as usize)?);
            let mut cols = Vec::with_capacity(n);
            for i in 0..rows.len() {
                let mut previous: Option<u32> = None;
                for _ in row_start[i]..row_start[i + 1] {
                    let gap = read_varint(&mut bytes)?;
                    let c = match previous {
                        None => Some(gap),
                        Some(p) => p.checked_add(gap).and_then(|c| c.checked_add(1)),
                    }
                    .ok_or_else(|| invalid("column past u32"))?;
                    cols.push(c);
                    previous = Some(c);
                }
            }
            if bytes.remaining() != 0 {
                return Err(invalid("trailing column bytes"));
            }
            let values = match r.u8()? {
                0 => r.f32s()?,
                form @ (1 | 2) if form == 1 || escaped_counts => {
                    let unit = r.f32()?;
                    let count = r.u64()?;
                    if count != n as u64 {
                        return Err(invalid("weight count differs from the entries"));
                    }
                    let counts = r.take(n)?;
                    // Form 2's escapes: one varint per count byte of 255 (none in form 1).
                    let mut extra = Reader::new(&[]);
                    if form == 2 {
                        let len = r.u64()?;
                        if len > r.remaining() as u64 {
                            return Err(invalid("escaped counts shorter than their length"));
                        }
                        extra = Reader::new(r.take(len as usize)?);
                    }
                    let mut values = Vec::with_capacity(n);
                    for &c in counts {
                        let c = if form == 2 && c == 255 {
                            read_varint(&mut extra)?
                                .checked_add(255)
                                .filter(|&c| c <= WIDEST_COUNT)
                                .ok_or_else(|| invalid("escaped count past 2^24"))?
                        } else {
                            c as u32
                        };
                        values.push(unit * c as f32);
                    }
                    if extra.remaining() != 0 {
                        return Err(invalid("trailing escaped count bytes"));
                    }
                    values
                }
                k => return Err(invalid(&format!("unknown weight form {k}"))),
            };
            Ok(Some(TexelGather {
                rows,
                row_start,
                cols,
                values,
                tiles: Default::default(),
            }))
        }
        k => Err(invalid(&format!("unknown gather flag {k}"))),
    }
}

fn read_varint(r: &mut Reader) -> Result<u32, WireError> {
    u32::try_from(r.varint()?).map_err(|_| WireError::Invalid("varint past u32".into()))
}

/// `(unit, counts)` when every value is exactly `unit · count` with `count ≤ 255` (the unit is
/// the smallest positive value; zero weights count 0): how the bundle stores gather weights and
/// how the client keeps them in memory.
pub fn gather_counts(values: &[f32]) -> Option<(f32, Vec<u8>)> {
    unit_counts(values, u8::MAX.into(), |c| c as u8)
}

/// [`gather_counts`] with counts up to 65,535: how the client keeps in memory the weights of a
/// gather some of whose counts exceed a byte (the bundle stores those as f32).
pub fn gather_counts_u16(values: &[f32]) -> Option<(f32, Vec<u16>)> {
    unit_counts(values, u16::MAX.into(), |c| c as u16)
}

/// `(unit, counts)` when every value is exactly `unit · count` with `count ≤ max` (each count
/// narrowed by `narrow`).
fn unit_counts<C>(values: &[f32], max: f32, narrow: impl Fn(f32) -> C) -> Option<(f32, Vec<C>)> {
    let unit = values
        .iter()
        .copied()
        .filter(|v| *v > 0.0)
        .fold(f32::INFINITY, f32::min);
    if !unit.is_finite() {
        return None;
    }
    values
        .iter()
        .map(|&v| {
            let count = (v / unit).round();
            ((0.0..=max).contains(&count) && unit * count == v).then(|| narrow(count))
        })
        .collect::<Option<Vec<C>>>()
        .map(|counts| (unit, counts))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// `g` written and read back with its index lists in either form (the same gather).
    fn round_trip(g: &TexelGather) -> TexelGather {
        let [plain, packed] = [IndexLists::Plain, IndexLists::Packed].map(|lists| {
            let mut w = Writer::new();
            let escaped = write_gather(&mut w, Some(g), lists, None);
            let mut r = Reader::new(&w.bytes);
            let out = read_gather(&mut r, escaped, lists, false).unwrap().unwrap();
            assert_eq!(r.remaining(), 0);
            out
        });
        assert_eq!(plain, packed);
        packed
    }

    #[test]
    fn rows_come_back_sorted_with_repeats_merged() {
        let unit = 1.0 / 1024.0;
        let g = TexelGather {
            rows: vec![3, 9],
            row_start: vec![0, 4, 6],
            cols: vec![70000, 5, 5, 0, 128, 127],
            values: vec![unit, 2.0 * unit, unit, 7.0 * unit, unit, 3.0 * unit],
            ..Default::default()
        };
        let out = round_trip(&g);
        assert_eq!(out.rows, vec![3, 9]);
        assert_eq!(out.row_start, vec![0, 3, 5]);
        assert_eq!(out.cols, vec![0, 5, 70000, 127, 128]);
        assert_eq!(
            out.values,
            vec![7.0 * unit, 3.0 * unit, unit, 3.0 * unit, unit]
        );
    }

    #[test]
    fn weights_that_are_not_counts_stay_f32() {
        let g = TexelGather {
            rows: vec![0],
            row_start: vec![0, 2],
            cols: vec![1, 2],
            values: vec![0.3, 0.7],
            ..Default::default()
        };
        assert_eq!(round_trip(&g), g);
    }

    proptest! {
        #[test]
        fn any_bytes_decode_or_fail_without_panicking(
            bytes in proptest::collection::vec(any::<u8>(), 0..200)
        ) {
            let mut b = vec![2u8];
            b.extend_from_slice(&bytes);
            let _ = read_gather(&mut Reader::new(&b), true, IndexLists::Plain, false);
            let _ = read_gather(&mut Reader::new(&b), true, IndexLists::Packed, true);
        }

        #[test]
        fn sorted_gathers_round_trip(
            rows in proptest::collection::vec(
                (proptest::collection::btree_set(0u32..100_000, 0..20), 1u32..=2000), 0..12)
        ) {
            let unit = 1.0 / 256.0;
            let mut g = TexelGather { row_start: vec![0], ..Default::default() };
            for (i, (cols, count)) in rows.iter().enumerate() {
                g.rows.push(i as u32 * 2);
                for c in cols {
                    g.cols.push(*c);
                    g.values.push(unit * *count as f32);
                }
                g.row_start.push(g.cols.len() as u32);
            }
            prop_assert_eq!(round_trip(&g), g);
        }
    }
}
